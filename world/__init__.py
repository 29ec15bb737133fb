"""The world every role shares: the 3D grid and its geometry (`world.grid`: `World`, `build_world`, the cell
arithmetic) and MovingAI's map and scenario formats (`world.movingai`). It imports only `schema`."""
