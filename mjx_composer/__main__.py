"""`python -m mjx_composer demo ...`."""

import sys

from mjx_composer import cli

sys.exit(cli.main())
