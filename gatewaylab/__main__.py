"""`python -m gatewaylab` is the `gatewaylab` command."""

import sys

from gatewaylab.cli.main import main

sys.exit(main())
