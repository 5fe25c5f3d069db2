"""``python -m tpods.cli``: the same as the ``tpods`` command."""

import sys

from tpods.cli import main

sys.exit(main())
