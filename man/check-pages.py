#!/usr/bin/env python3
# SPDX-License-Identifier: MIT OR Apache-2.0
"""Structural checks of the manual (called by c-tests/suites/man.sh).

    check-pages.py --exports FILE --headers DIR --pages DIR [--debian-man DIR]

Prints one "ok   - ..." or "FAIL - ..." line per check:
  - every row of the table of the exports (FILE: abi/exports.txt, rows
    "name | header | since | page") has its page: man/src/PAGE.md lists the name,
    and DIR/man3/NAME.3 was made from it; every section-3 page documents a row;
  - every section-3 source has the sections SYNOPSIS, DESCRIPTION, RETURN VALUE,
    ERRORS, EXAMPLE and SEE ALSO, in that order, and an example code block;
  - no EXAMPLE ignores what an _async submit returns (a statement of its own);
  - every function named by a page is declared in its SYNOPSIS, with the prototype
    the headers in --headers declare (whitespace aside);
  - SEE ALSO and inline references NAME(3)/NAME(7) point to pages that exist (or to
    system pages in sections 1, 2 and 3 that are not modbus_* names);
  - with --debian-man (libmodbus' own pages), no run of 8 words of running text
    is shared with the libmodbus page of the same name (clean-room guard).
"""

import argparse
import gzip
import os
import re
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import importlib.util  # noqa: E402

spec = importlib.util.spec_from_file_location("genman", os.path.join(HERE, "gen-man.py"))
genman = importlib.util.module_from_spec(spec)
spec.loader.exec_module(genman)

REQUIRED = ["SYNOPSIS", "DESCRIPTION", "RETURN VALUE", "ERRORS", "EXAMPLE", "SEE ALSO"]

results = {"passed": 0, "failed": 0}


def ok(msg):
    results["passed"] += 1
    print("ok   - " + msg)


def fail(msg, *details):
    results["failed"] += 1
    print("FAIL - " + msg)
    for d in details:
        print("       " + d)


def normalize(proto):
    p = proto.replace("MODBUS_API", " ")
    p = re.sub(r"/\*.*?\*/", " ", p, flags=re.S)
    p = re.sub(r"\s+", " ", p).strip()
    p = re.sub(r"\s*\*\s*", " * ", p)
    p = re.sub(r"\s*([(),;])\s*", r"\1", p)
    p = re.sub(r"\s+", " ", p).strip()
    return p


def header_prototypes(hdir):
    """name -> normalized prototype, from every MODBUS_API declaration."""
    protos = {}
    for fname in sorted(os.listdir(hdir)):
        if not fname.endswith(".h"):
            continue
        with open(os.path.join(hdir, fname), encoding="utf-8") as f:
            text = f.read()
        text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
        for m in re.finditer(r"MODBUS_API\s+([^;{}#]*?\b(\w+)\s*\([^;]*?\)\s*;)", text, flags=re.S):
            protos[m.group(2)] = normalize(m.group(1))
        for m in re.finditer(r"^\s*extern\s+([^;]*?\b(\w+)\s*;)", text, flags=re.M):
            protos.setdefault(m.group(2), normalize("extern " + m.group(1)))
    return protos


def synopsis_prototypes(page):
    """name -> normalized prototype, from the C blocks of the SYNOPSIS."""
    protos = {}
    for heading, lang, code in page["blocks"]:
        if heading != "SYNOPSIS" or lang != "c":
            continue
        text = "\n".join(l for l in code.splitlines() if not l.lstrip().startswith("#"))
        for m in re.finditer(r"([^;{}]*?\b(\w+)\s*\([^;]*?\)\s*;)", text, flags=re.S):
            protos[m.group(2)] = normalize(m.group(1))
        for m in re.finditer(r"^\s*(extern\s+[^;]*?\b(\w+)\s*;)", text, flags=re.M):
            protos[m.group(2)] = normalize(m.group(1))
    return protos


def debian_text(path):
    """Rendered text of a (gzipped) page, SYNOPSIS and indented code left out."""
    with gzip.open(path, "rb") if path.endswith(".gz") else open(path, "rb") as f:
        data = f.read()
    return render_words(data)


def render_words(roff_bytes):
    env = dict(os.environ, MANWIDTH="200", MAN_KEEP_FORMATTING="")
    out = subprocess.run(
        ["man", "-l", "-"], input=roff_bytes, capture_output=True, env=env
    ).stdout.decode("utf-8", "replace")
    out = re.sub(r".\x08", "", out)
    words = []
    section = ""
    for line in out.splitlines():
        if re.match(r"^[A-Z][A-Z ]+$", line.strip()) and not line.startswith(" "):
            section = line.strip()
            continue
        if section in ("SYNOPSIS", "NAME", "SEE ALSO", "EXAMPLE", "EXAMPLES"):
            continue
        # Code is indented deeper than running text (7 columns).
        if re.match(r"^ {9,}", line):
            continue
        words.extend(w.lower().strip(".,;:()\"'") for w in line.split())
    return [w for w in words if w]


def shingles(words, n):
    return {" ".join(words[i:i + n]) for i in range(len(words) - n + 1)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--exports", required=True)
    ap.add_argument("--headers", required=True)
    ap.add_argument("--pages", required=True)
    ap.add_argument("--debian-man")
    args = ap.parse_args()

    rows = {}
    with open(args.exports, encoding="utf-8") as f:
        for line in f:
            if line.strip() and not line.lstrip().startswith("#"):
                fields = [x.strip() for x in line.split("|")]
                if len(fields) != 4:
                    fail("%s: a row is name | header | since | page" % args.exports, line.strip())
                    continue
                rows[fields[0]] = fields[3]
    exported = sorted(rows)
    pages = genman.load_pages()
    by_name = {}
    for p in pages:
        for n in p["names"]:
            by_name[n] = p

    # 1. Each row's page, and no page without a row.
    man3 = os.path.join(args.pages, "man3")
    bad = []
    for name in exported:
        source = os.path.join(genman.SRC, rows[name] + ".md")
        page = next((p for p in pages if p["path"] == source), None)
        if page is None or page["section"] != "3":
            bad.append("%s: its page man/src/%s.md does not exist (or is not in section 3)" % (name, rows[name]))
        elif name not in page["names"]:
            bad.append("%s: man/src/%s.md does not list it in names:" % (name, rows[name]))
        elif not os.path.isfile(os.path.join(man3, name + ".3")):
            bad.append("%s: no %s/%s.3 generated" % (name, man3, name))
    if bad:
        fail("every row of %s has its page in section 3 (%d rows)" % (args.exports, len(exported)), *bad)
    else:
        ok("every row of %s has its page in section 3 (%d rows)" % (args.exports, len(exported)))
    stale = sorted(n for p in pages if p["section"] == "3" for n in p["names"] if n not in rows)
    if stale:
        fail("every section-3 page documents a row of %s" % args.exports, "no row: " + ", ".join(stale))
    else:
        ok("every section-3 page documents a row of %s" % args.exports)

    # 2. Sections.
    bad = []
    for p in pages:
        if p["section"] != "3":
            continue
        order = [h for h in p["headings"] if h in REQUIRED]
        if order != REQUIRED:
            bad.append("%s: sections %s" % (os.path.basename(p["path"]), p["headings"]))
        elif not any(h == "EXAMPLE" and lang == "c" for h, lang, _ in p["blocks"]):
            bad.append("%s: no C code block in EXAMPLE" % os.path.basename(p["path"]))
    if bad:
        fail("every section-3 page has SYNOPSIS, DESCRIPTION, RETURN VALUE, ERRORS, EXAMPLE, SEE ALSO", *bad)
    else:
        ok("every section-3 page has SYNOPSIS, DESCRIPTION, RETURN VALUE, ERRORS, EXAMPLE, SEE ALSO")

    # 2b. An example that queues a request checks that it was queued: a submit's -1
    # (EAGAIN, ESHUTDOWN...) means its callback never runs.
    bad = []
    for p in pages:
        for h, lang, text in p["blocks"]:
            if h != "EXAMPLE" or lang != "c":
                continue
            for line in text.splitlines():
                if re.match(r"\s*(\(void\)\s*)?modbus_\w+_async\s*\(.*\)\s*;\s*$", line):
                    bad.append("%s: %s" % (os.path.basename(p["path"]), line.strip()))
    if bad:
        fail("no EXAMPLE ignores what an _async submit returns", *bad)
    else:
        ok("no EXAMPLE ignores what an _async submit returns")

    # 3. Prototypes.
    hdr = header_prototypes(args.headers)
    bad = []
    checked = 0
    for p in pages:
        if p["section"] != "3":
            continue
        syn = synopsis_prototypes(p)
        for n in p["names"]:
            if n not in syn:
                bad.append("%s: not declared in the SYNOPSIS" % n)
            elif n not in hdr:
                bad.append("%s: not declared in %s" % (n, args.headers))
            elif syn[n] != hdr[n]:
                bad.append("%s: page says  %s" % (n, syn[n]))
                bad.append("%s  header says %s" % (" " * len(n), hdr[n]))
            else:
                checked += 1
    if bad:
        fail("SYNOPSIS prototypes equal the headers' (%d equal)" % checked, *bad)
    else:
        ok("SYNOPSIS prototypes equal the headers' (%d functions and objects)" % checked)
    undocumented = sorted(n for n in hdr if n not in by_name)
    if undocumented:
        fail("every function declared in the headers has a page", "no page: " + ", ".join(undocumented))
    else:
        ok("every function declared in the headers has a page (%d)" % len(hdr))

    # 4. Cross references.
    known = {(n, p["section"]) for p in pages for n in p["names"]}
    bad = set()
    for p in pages:
        with open(p["path"], encoding="utf-8") as f:
            text = f.read()
        for m in genman.XREF.finditer(text):
            name, sec = m.group(1), m.group(2)
            ours = name.startswith(("modbus_", "rsmodbus", "libmodbus"))
            if (name, sec) not in known and (ours or sec not in "123"):
                bad.add("%s: %s(%s)" % (os.path.basename(p["path"]), name, sec))
    if bad:
        fail("cross references point to existing pages", *sorted(bad))
    else:
        ok("cross references point to existing pages")

    # 5. Clean room: no 8-word run shared with libmodbus' page of the same name.
    if args.debian_man:
        compared = 0
        bad = []
        for p in pages:
            for n in p["names"]:
                deb = os.path.join(args.debian_man, "man%s" % p["section"], "%s.%s.gz" % (n, p["section"]))
                if not os.path.exists(deb):
                    continue
                ours_path = os.path.join(args.pages, "man%s" % p["section"], "%s.%s" % (n, p["section"]))
                with open(ours_path, "rb") as f:
                    ours = shingles(render_words(f.read()), 8)
                theirs = shingles(debian_text(deb), 8)
                common = sorted(ours & theirs)
                compared += 1
                if common:
                    bad.append("%s: %s" % (n, " | ".join(common[:3])))
        if compared == 0:
            fail("clean room: libmodbus' pages found for comparison in %s" % args.debian_man)
        elif bad:
            fail("clean room: no 8-word run shared with libmodbus' pages (%d compared)" % compared, *bad)
        else:
            ok("clean room: no 8-word run shared with libmodbus' pages (%d compared)" % compared)

    return 0 if results["failed"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
