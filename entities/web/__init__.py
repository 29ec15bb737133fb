"""The browser ground station, ``dronesim gcs --web [HOST:]PORT`` (live) or ``--replay JOURNAL`` (docs/web-gcs.md):
`model` and `replay` are pure (what the page shows, and decides), `server` the HTTP side (standard library),
`node` the Zenoh adapter, `static/` the page itself (no external library, no CDN).
"""
