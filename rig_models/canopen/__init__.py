"""The virtual rig's CANopen devices: `node.VirtualNode` (CiA 301: NMT, SDO server, SYNC and
PDOs, heartbeat, EMCY, from an EDS) and `profiles` (CiA 402 drive, CiA 401 I/O, CiA 406
encoder) on top of it.

May import: `canopen` (object dictionary parsing and types only), `drivers.canopen_pdo`,
`drivers.dbc` (FrameError), `drivers.binding.canopen` (the bounded EDS reader and the
binding the rig file made), `rig_models.schema` (ConfigError). Never `harness`, never the
rig's physics: raw CANopen values in and out; the virtual rig's glue (`rig_devices`) maps them to SI
with the rig file. No threads: the owner pumps `handle()` and `poll()`.
"""
