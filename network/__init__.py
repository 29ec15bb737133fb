"""The Zenoh layer under every process: sessions, flags and the budgeted inbox (`network.transport`), joining a
game (`network.membership`), the turn an entity believes the game is at (`network.clock`), and stopping on a
signal (`network.signals`). It imports only `schema`."""
