"""Child process for the cross-process test: a canopen LocalNode on a gatewaylab bus via the plugin."""

import sys

import canopen

endpoint = sys.argv[1]
od = canopen.ObjectDictionary()
var = canopen.objectdictionary.ODVariable("Manufacturer device name", 0x1008)
var.data_type = canopen.objectdictionary.VISIBLE_STRING
var.access_type = "ro"
var.default = "LocalNode in another process"
od.add_object(var)
value = canopen.objectdictionary.ODVariable("Counter", 0x2001)
value.data_type = canopen.objectdictionary.UNSIGNED16
value.access_type = "rw"
value.default = 4242
od.add_object(value)
network = canopen.Network()
network.connect(interface="gatewaylab", channel=endpoint, name="local-node-process")
network.create_node(7, od)
print("ready", flush=True)
sys.stdin.read()  # run until the parent closes our stdin
network.disconnect()
