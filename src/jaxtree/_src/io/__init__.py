"""Results out of the engine: ``results`` (NetCDF result files with units and provenance),
``output`` (npz and CSV exports, summaries), the matplotlib figures (``figures``: their shared
style and PNG write; ``history_plots``, ``mode_plots``, ``work_precision_plot``), ``viewer`` (the
self-contained 3D page) and ``files`` (atomic writes, for every file the package writes).
"""
