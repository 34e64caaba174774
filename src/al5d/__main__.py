"""`python -m al5d`: the `al5d` command line."""

import sys

from al5d.app.entry import main

sys.exit(main())
