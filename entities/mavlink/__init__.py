"""The MAVLink face of the ground station (docs/mavlink.md): every drone of the game a MAVLink vehicle.

`geo` maps cells to local NED metres and WGS84; `vehicle` is one drone's vehicle (modes, arming, commands,
the mission protocol) and `bridge` the fleet's core around the ground station's protocol, both pure; `node` is
the adapter (UDP sockets, pymavlink's encoding and decoding, the game's link)."""
