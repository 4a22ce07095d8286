from apt_filters.cli.main import run

run()
