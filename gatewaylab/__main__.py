"""`python -m gatewaylab` is the `gatewaylab` command."""

import sys

from gatewaylab.rig.cli import main

sys.exit(main())
