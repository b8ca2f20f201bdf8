"""``python -m mpmjax.cli ARGS``: the ``mpmjax`` command."""

import sys

from ._commands import main

if __name__ == "__main__":  # not on a plain import (tests/test_architecture.py imports every module)
    sys.exit(main())
