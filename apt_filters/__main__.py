import sys

from apt_filters.cli.main import main

sys.exit(main())
