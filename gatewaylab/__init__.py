"""gatewaylab: byte-exact emulators of industrial CAN gateways on shared virtual CAN buses."""

__version__ = "0.1.0"

from gatewaylab import _moved

_moved.install()
