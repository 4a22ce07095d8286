"""apt-filters: atom probe tomography iso-surfaces, MeshLab filter chains and interface chemistry.

The pipeline flows one way, one package per step::

    io -> voxel -> contour -> meshlab / remesh -> analysis -> cli

``core`` holds the few types every step shares (errors, :class:`~apt_filters.core.mesh.TriMesh`,
atomic file output).
"""

__version__ = "0.1.0"
