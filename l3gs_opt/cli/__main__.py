"""``python -m l3gs_opt.cli``: the command line."""

import sys

from l3gs_opt.cli.main import main

sys.exit(main())
