"""The browser ground station: ``dronesim gcs --web [HOST:]PORT`` (live) or ``--replay JOURNAL``.

* `model` -- pure: what the page shows (world, drones, trails, targets, turn, event log), the checks on
  the human's input, and when the ground station answers its phase (pacing, pause, step, quit);
* `replay` -- pure: a journal turned into frames the page plays;
* `server` -- the HTTP server (standard library): static page, JSON API, Server-Sent Events;
* `node` -- the Zenoh adapter: one main thread owns the model; HTTP threads talk to it through a queue;
* `static/` -- the page itself (HTML, JavaScript, CSS; no external library, no CDN).

See docs/web-gcs.md.
"""
