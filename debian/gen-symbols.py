#!/usr/bin/env python3
# SPDX-License-Identifier: MIT OR Apache-2.0
"""Writes debian/librsmodbus5.symbols (dpkg-gensymbols format) from the ABI data
that scripts/check-symbols.sh enforces, so the package follows the exports:

  - abi/debian-libmodbus5.symbols: Debian's libmodbus5 symbols with their minimum
    versions, minus the "omit" rows of abi/symbols-intended-differences.txt;
  - the "api" rows (libmodbus functions newer than 3.1.6), at the libmodbus version
    named in their reason ("libmodbus 3.1.9 API");
  - the "extension" rows (rsmodbus' own), at this package's version, with the
    alternative dependency template 1 (librsmodbus5): libmodbus5 lacks them.

The package version is <libmodbus API level>+rs<rsmodbus version> (3.1.12+rs0.1.0):
above every libmodbus version it implements, so that dpkg-gensymbols keeps the
minimum versions (it lowers any that is above the package's version).

A program built against librsmodbus-dev that uses only libmodbus' functions then
depends on "libmodbus5 (>= V)", which Debian's libmodbus5 and librsmodbus5 (it
provides libmodbus5) both satisfy; one that uses an extension depends on
librsmodbus5. dh_makeshlibs -c4 fails the build when the exports differ.

Usage: debian/gen-symbols.py PACKAGE_VERSION > debian/librsmodbus5.symbols
"""
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    version = sys.argv[1]
    rows = {"omit": [], "api": [], "extension": []}
    reasons = {}
    with open(os.path.join(ROOT, "abi", "symbols-intended-differences.txt"), encoding="utf-8") as f:
        for line in f:
            if line.startswith("#") or "|" not in line:
                continue
            kind, name, reason = (x.strip() for x in line.split("|", 2))
            if kind in rows:
                rows[kind].append(name)
                reasons[name] = reason
    symbols = {}
    with open(os.path.join(ROOT, "abi", "debian-libmodbus5.symbols"), encoding="utf-8") as f:
        for line in f:
            m = re.match(r"^ (\S+)@Base (\S+)", line)
            if m and m.group(1) not in rows["omit"]:
                symbols[m.group(1)] = m.group(2)
    for name in rows["api"]:
        m = re.search(r"libmodbus (\d+\.\d+\.\d+)", reasons[name])
        if not m:
            sys.exit("gen-symbols: no 'libmodbus X.Y.Z' version in the reason of %s" % name)
        symbols[name] = m.group(1)
    out = [
        "libmodbus.so.5 libmodbus5 #MINVER#",
        "| librsmodbus5 #MINVER#",
        "* Build-Depends-Package: libmodbus-dev",
    ]
    for name in sorted(set(symbols) | set(rows["extension"])):
        if name in rows["extension"]:
            out.append(" %s@Base %s 1" % (name, version))
        else:
            out.append(" %s@Base %s" % (name, symbols[name]))
    print("\n".join(out))


if __name__ == "__main__":
    main()
