#!/usr/bin/env python3
"""The Rust crates linked into libmodbus.so.5, libmodbus.a and rsmodbus-gateway, for
debian/copyright.

The packages ship code of the crates the library depends on (rustls, ring, the
RustCrypto crates, libc, ...) and those the gateway adds (nix, ...), statically linked. debian/copyright names each of them,
with its licence and copyright holders, in the header's Comment, between two marker
lines; this script writes that list from Cargo.lock (the normal dependencies of the
rsmodbus and rsmodbus-gateway crates, not the build tools), reading each crate's copyright lines from its
licence files in cargo's registry.

    python3 debian/embedded-crates.py           rewrites the list in debian/copyright
    python3 debian/embedded-crates.py --check   exit 1 if the list is out of date
                                                (c-tests/suites/package.sh runs it)

Every licence the list names must have a License paragraph in debian/copyright.

SPDX-License-Identifier: MIT OR Apache-2.0
"""
import json
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COPYRIGHT = os.path.join(ROOT, "debian", "copyright")
BEGIN = " Rust crates statically linked into the library and the gateway (from crates.io, at"
END = " (End of the list written by debian/embedded-crates.py.)"
OURS = {"rsmodbus", "rsmodbus-proto", "rsmodbus-gateway"}


def metadata():
    cmd = ["cargo", "metadata", "--format-version", "1", "--locked", "--filter-platform",
           "x86_64-unknown-linux-gnu"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:
        out = subprocess.run(cmd + ["--offline"], cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def linked(meta, name):
    """The packages reached from the crate NAME through normal (not build or dev) dependencies."""
    packages = {p["id"]: p for p in meta["packages"]}
    nodes = {n["id"]: n for n in meta["resolve"]["nodes"]}
    root = next(p["id"] for p in meta["packages"] if p["name"] == name)
    seen, todo = set(), [root]
    while todo:
        node = nodes[todo.pop()]
        for dep in node["deps"]:
            if any(k["kind"] is None for k in dep["dep_kinds"]) and dep["pkg"] not in seen:
                seen.add(dep["pkg"])
                todo.append(dep["pkg"])
    return sorted((packages[i] for i in seen if packages[i]["name"] not in OURS),
                  key=lambda p: (p["name"], p["version"]))


def holders(package):
    """The distinct copyright lines of the crate's licence files, or its authors."""
    folder = os.path.dirname(package["manifest_path"])
    found = []
    for name in sorted(os.listdir(folder)):
        if not re.match(r"(LICEN[CS]E|COPYING|COPYRIGHT)", name, re.I):
            continue
        try:
            text = open(os.path.join(folder, name), encoding="utf-8", errors="replace").read()
        except OSError:
            continue
        for line in text.splitlines():
            line = re.sub(r"^[\s/#*]*", "", line).strip()
            # A holder's line, not the licence's own words about "the above copyright notice".
            if re.match(r"Copyright\s+(\(c\)\s*)?[0-9]", line, re.I) and line not in found:
                found.append(line)
    if found:
        return "; ".join(found)
    authors = ", ".join(re.sub(r"\s*<[^>]*>", "", a) for a in package["authors"])
    return f"the {package['name']} authors" + (f" ({authors})" if authors else "")


def block(meta):
    lines = [BEGIN, " the versions of Cargo.lock; each under the licence its manifest states, texts below):"]
    library = {p["id"] for p in linked(meta, "rsmodbus")}
    both = {p["id"]: p for p in linked(meta, "rsmodbus") + linked(meta, "rsmodbus-gateway")}
    for p in sorted(both.values(), key=lambda p: (p["name"], p["version"])):
        only = "" if p["id"] in library else " (the gateway only)"
        lines.append(f"  - {p['name']} {p['version']}{only}: {p['license']}; {holders(p)}")
    lines.append(END)
    return lines


def main():
    check = sys.argv[1:] == ["--check"]
    text = open(COPYRIGHT, encoding="utf-8").read().split("\n")
    new = block(metadata())
    if BEGIN in text:
        start, end = text.index(BEGIN), text.index(END)
        updated = text[:start] + new + text[end + 1:]
    else:
        # After the header's Comment, before the first blank line.
        first_blank = text.index("")
        updated = text[:first_blank] + [" ."] + new + text[first_blank:]
    licences = set(re.findall(r"[A-Za-z0-9.-]+", " ".join(line.split(":", 1)[1].split(";")[0]
                                                          for line in new if line.startswith("  - "))))
    licences -= {"AND", "OR", "WITH"}
    have = " ".join(line for line in updated if line.startswith("License:"))
    missing = sorted(lic for lic in licences if lic not in have)
    if missing:
        print(f"debian/copyright has no License paragraph for: {', '.join(missing)}")
        sys.exit(1)
    if check:
        if updated != text:
            print("debian/copyright: the list of linked crates is out of date: run python3 debian/embedded-crates.py")
            sys.exit(1)
        print(f"debian/copyright lists the {len(new) - 3} linked crates")
        return
    with open(COPYRIGHT, "w", encoding="utf-8") as f:
        f.write("\n".join(updated))
    print(f"debian/copyright: {len(new) - 3} linked crates")


if __name__ == "__main__":
    main()
