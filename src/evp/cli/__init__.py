"""The ``evp`` command line: one module per command group, assembled by :mod:`evp.cli.app`.

``main`` is here because it is the entry point pyproject.toml names (``evp = evp.cli:main``).
"""

from evp.cli.app import main

__all__ = ["main"]
