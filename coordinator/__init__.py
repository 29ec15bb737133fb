"""The coordinator (the seed's SRV with its observer OBS): the pure turn engine, the observer's rules,
the journal, and the Zenoh adapter (node.py)."""
