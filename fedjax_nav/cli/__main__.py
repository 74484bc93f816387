"""`python -m fedjax_nav.cli ...` = `fedjax-nav ...`."""

import sys

from fedjax_nav.cli import main

sys.exit(main())
