"""The simulation's entities: the world and environment, drones and their autopilots, the ground station.

Pure cores (world.py, autopilots/) have no network code; the Zenoh adapters are the *_node.py modules.
"""
