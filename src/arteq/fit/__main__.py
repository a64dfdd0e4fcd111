"""``python -m arteq.fit``: the same as the ``arteq-fit`` command."""

import sys

from arteq.fit.cli import main

sys.exit(main())
