"""``dronesim router``: a standalone Zenoh router in Python, for multi-host runs without zenohd.

It listens on the given endpoints (default tcp/0.0.0.0:7447), prints where, and runs until SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import signal
import sys

from network.transport import (
    add_zenoh_args,
    apply_flags,
    connect_to,
    open_session,
    router_config,
    router_locators,
    setup_logging,
    zenoh_config,
)
from schema import UsageError


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim router", description=__doc__)
    add_zenoh_args(p)
    args = p.parse_args(argv)
    setup_logging(args.log_level, "ROUTER")
    try:
        if args.config:
            conf = zenoh_config(args)
        else:
            conf = router_config(args.listen or "tcp/0.0.0.0:7447")
            connect_to(conf, args.connect)
            apply_flags(conf, args, router=True)
        conf.insert_json5("mode", '"router"')
        session = open_session(conf)
    except UsageError as err:  # (a bad endpoint, one it cannot listen on or reach)
        print(f"dronesim router: {err}", file=sys.stderr)
        return 2
    signals = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, signals)  # delivered to sigwait below, not as exceptions
    with session:
        print(f"router {session.info.zid()} listening on {', '.join(router_locators(session))}", flush=True)
        signal.sigwait(signals)
    return 0


if __name__ == "__main__":
    sys.exit(cli())
