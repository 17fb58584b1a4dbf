"""``canopen_node``: any CANopen device from its EDS or DCF (device.py the node, rig.py its rig-file kind)."""
