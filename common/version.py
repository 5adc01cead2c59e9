"""The version of snan-hil, defined here once: pyproject.toml reads it (``[tool.setuptools.
dynamic]``), ``snan_hil.__version__`` is this one, and results, reports, checkpoints and the
chip's history record it. A base module (imports nothing) so every layer may import it."""

__version__ = "0.1.0"
