"""A stranger on the robot's network, written with PyPI eclipse-zenoh only
(nothing of ours): it connects as a zenoh client to ENDPOINT with whatever
credentials it holds, listens on the given keys, puts the given forged
payloads, and reports what it could do as one JSON line:

  {"opened": bool, "error": str, "received": {key: n}, "bytes": n, "put": n}

--ca / --cert / --key: the CA it trusts and the certificate and key it shows
(none: plain or certificate-less). --read KEY (repeatable): subscribe.
--forge KEY=FILE (repeatable): put FILE's bytes on KEY, --times times each.
"""

import argparse
import json
import time

import zenoh


def config(args):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # Give up on the endpoint after a few seconds rather than retrying.
    conf.insert_json5("connect/timeout_ms", "5000")
    tls = {}
    if args.ca:
        tls["root_ca_certificate"] = args.ca
    if args.cert:
        tls.update(enable_mtls=True, connect_certificate=args.cert, connect_private_key=args.key)
    if tls:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    return conf


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    p.add_argument("--ca")
    p.add_argument("--cert")
    p.add_argument("--key")
    p.add_argument("--read", action="append", default=[])
    p.add_argument("--forge", action="append", default=[])
    p.add_argument("--times", type=int, default=20)
    p.add_argument("--seconds", type=float, default=3.0)
    args = p.parse_args()
    started = time.monotonic()
    report = {"opened": False, "error": "", "received": {}, "bytes": 0, "put": 0}
    try:
        session = zenoh.open(config(args))
    except Exception as e:  # zenoh raises its own ZError
        report["error"] = str(e).splitlines()[0] if str(e) else type(e).__name__
        report["seconds"] = round(time.monotonic() - started, 2)
        print(json.dumps(report), flush=True)
        return
    report["opened"] = True

    def counter(key):
        report["received"][key] = 0

        def on_sample(sample):
            report["received"][key] += 1
            report["bytes"] += len(sample.payload.to_bytes())
        return on_sample

    # Only what comes over the link counts, not its own puts.
    subscribers = [
        session.declare_subscriber(key, counter(key), allowed_origin=zenoh.Locality.REMOTE)
        for key in args.read
    ]
    time.sleep(0.5)
    forged = []
    for spec in args.forge:
        key, path = spec.split("=", 1)
        with open(path, "rb") as f:
            forged.append((key, f.read()))
    for _ in range(args.times):
        for key, payload in forged:
            session.put(key, payload, allowed_destination=zenoh.Locality.REMOTE)
            report["put"] += 1
        time.sleep(0.02)
    time.sleep(args.seconds)
    for s in subscribers:
        s.undeclare()
    session.close()
    report["seconds"] = round(time.monotonic() - started, 2)
    print(json.dumps(report), flush=True)


if __name__ == "__main__":
    main()
