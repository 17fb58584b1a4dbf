"""`python -m gatewaylab` is the `gatewaylab` command."""

import sys

from .rig.cli import main

sys.exit(main())
