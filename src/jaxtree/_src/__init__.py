"""jaxtree's implementation, one module per idea of the seed (``docs/architecture.md``).

Not a public API: names here may change without notice. The public surface is the package
``jaxtree`` itself (its ``__all__``).
"""

VERSION = "0.1.0"  # the package's version (pyproject.toml), read by jaxtree.__version__ and result files
