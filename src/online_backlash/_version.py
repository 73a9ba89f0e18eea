"""The package version, stated once (read by pyproject.toml and ``online_backlash.__version__``)."""

__version__ = "0.1.0"
