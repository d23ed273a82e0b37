#!/usr/bin/env python3
"""Validate every message of an MCAP file written by `ianav export-mcap` against Foxglove's
published JSON schemas (the npm package @foxglove/schemas), by schema name.

    npm pack @foxglove/schemas && tar xzf foxglove-schemas-*.tgz    # -> ./package
    pip install mcap jsonschema
    python3 tools/mcap_foxglove_check.py FILE.mcap --schemas package

Prints each topic's message count and how many failed validation (with the first failure);
exits 1 if any did. Topics whose schema Foxglove does not publish (`ianav.Status`) are counted
and not validated.
"""
import argparse
import collections
import json
import subprocess
import sys

import jsonschema
from mcap.reader import make_reader

DUMP = """
const s = require(require("path").resolve(process.argv[1], "jsonschema.js"));
const out = {};
for (const k of Object.keys(s)) { out[s[k].title || k] = s[k]; }
process.stdout.write(JSON.stringify(out));
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mcap")
    ap.add_argument("--schemas", required=True, help="the unpacked @foxglove/schemas package")
    args = ap.parse_args()
    dumped = subprocess.run(
        ["node", "-e", DUMP, args.schemas], check=True, capture_output=True, text=True
    )
    schemas = json.loads(dumped.stdout)
    counts, bad = collections.Counter(), collections.Counter()
    with open(args.mcap, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            counts[channel.topic] += 1
            ref = schemas.get(schema.name)
            if ref is None:
                continue
            try:
                jsonschema.validate(json.loads(message.data), ref)
            except jsonschema.ValidationError as e:
                if bad[channel.topic] == 0:
                    print(f"{channel.topic} ({schema.name}): {e.message[:300]}")
                bad[channel.topic] += 1
    for topic in sorted(counts):
        print(f"{topic}: {counts[topic]} messages, {bad[topic]} invalid")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
