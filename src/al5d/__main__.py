"""`python -m al5d`: the `al5d` command line."""

import sys

from al5d.app.cli import main

sys.exit(main())
