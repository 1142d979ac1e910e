#!/usr/bin/env python3
# SPDX-License-Identifier: MIT OR Apache-2.0
"""Writes debian/librsmodbus5.symbols (dpkg-gensymbols format) from the table of
the exports, abi/exports.txt (which c-tests/suites/symbols.sh compares with the
library), so the package follows the exports: every row at its "since" version,
which for the symbols of Debian's libmodbus5 is the minimum version of Debian's own
symbols file (abi/debian-libmodbus5.symbols; symbols.sh checks that they
agree), for later libmodbus functions the libmodbus release that added them, and
for rsmodbus' own ("rsmodbus") this package's version, with the alternative
dependency template 1 (librsmodbus5): libmodbus5 lacks them.

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
    symbols = {}
    with open(os.path.join(ROOT, "abi", "exports.txt"), encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            fields = [x.strip() for x in line.split("|")]
            if len(fields) != 4 or not re.fullmatch(r"\d+\.\d+\.\d+|rsmodbus", fields[2]):
                sys.exit("gen-symbols: abi/exports.txt:%d: not name | header | since | page" % number)
            symbols[fields[0]] = fields[2]
    out = [
        "libmodbus.so.5 libmodbus5 #MINVER#",
        "| librsmodbus5 #MINVER#",
        "* Build-Depends-Package: libmodbus-dev",
    ]
    for name in sorted(symbols):
        if symbols[name] == "rsmodbus":
            out.append(" %s@Base %s 1" % (name, version))
        else:
            out.append(" %s@Base %s" % (name, symbols[name]))
    print("\n".join(out))


if __name__ == "__main__":
    main()
