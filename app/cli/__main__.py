"""``python -m app.cli``: the ``mimica`` command."""

import sys

from app.cli import main

sys.exit(main())
