"""``python -m evp.cli``: the same as the ``evp`` command."""

from evp.cli.app import main

main()
