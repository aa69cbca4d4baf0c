"""Results out of the engine: ``results`` (NetCDF result files with units and provenance),
``output`` (npz and CSV exports, summaries), ``plots`` (matplotlib figures), ``viewer`` (the
self-contained 3D page) and ``files`` (atomic writes, for every file the package writes).
"""
