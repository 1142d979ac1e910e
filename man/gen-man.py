#!/usr/bin/env python3
# SPDX-License-Identifier: MIT OR Apache-2.0
"""Generates the rsmodbus manual pages (roff, man macros) from man/src/*.md.

man/src is the single source of the manual. Each file is one page in a small,
strict Markdown dialect:

    ---
    names: modbus_get_float_abcd, modbus_get_float_badc
    summary: read a float from two registers
    section: 3            (optional, default 3)
    ---
    ## SYNOPSIS           -> .SH        ### Sub -> .SS
    paragraphs            -> .PP        (blank-line separated)
    ```c ... ```          -> .EX/.EE    (code, indented)
    - item                -> bullet     (continuation lines indented by 2)
    `TERM`                -> .TP        (a term line followed by ":   text"
    :   text                             lines: a definition list)
    `code`  **bold**  *italic*  and NAME(3) cross references inline.

Every name in `names` gets its own page (NAME.SECTION) with the same text; the
NAME section lists all of them. Usage:

    gen-man.py [--out DIR] [--list] [--check]
      --out DIR   write DIR/man3/*.3 and DIR/man7/*.7 (default target/man)
      --list      print "name section source" for every page, write nothing
      --check     parse everything, report errors, write nothing
"""

import argparse
import datetime
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SRC = os.path.join(HERE, "src")


class PageError(Exception):
    pass


def project_version():
    with open(os.path.join(ROOT, "Cargo.toml"), encoding="utf-8") as f:
        for line in f:
            m = re.match(r'^version\s*=\s*"([^"]+)"', line)
            if m:
                return m.group(1)
    return "unknown"


def page_date():
    """SOURCE_DATE_EPOCH if set, else the date of the newest debian/changelog entry."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch:
        return datetime.datetime.fromtimestamp(int(epoch), datetime.timezone.utc).strftime("%Y-%m-%d")
    try:
        with open(os.path.join(ROOT, "debian", "changelog"), encoding="utf-8") as f:
            for line in f:
                m = re.match(r"^ -- .*>  (.+)$", line)
                if m:
                    d = datetime.datetime.strptime(m.group(1).strip(), "%a, %d %b %Y %H:%M:%S %z")
                    return d.strftime("%Y-%m-%d")
    except (OSError, ValueError):
        pass
    return "2026-01-01"


# ---------------------------------------------------------------- roff escaping

def escape_text(s):
    """Escapes plain text for roff (no font changes)."""
    s = s.replace("\\", "\\e")
    return s


def escape_code(s):
    """Escapes code: backslashes, and '-' as a real minus sign."""
    return s.replace("\\", "\\e").replace("-", "\\-")


def protect_line_start(line):
    """A roff text line must not start with '.' or '\''."""
    if line.startswith(".") or line.startswith("'"):
        return "\\&" + line
    return line


XREF = re.compile(r"\b([A-Za-z_][A-Za-z0-9_.-]*)\(([1-8])\)")
INLINE = re.compile(r"`([^`]+)`|\*\*([^*]+)\*\*|\*([^*\s][^*]*)\*")


def inline(text):
    """Converts inline Markdown (code, bold, italic, NAME(n) references)."""
    out = []
    pos = 0
    for m in INLINE.finditer(text):
        out.append(plain(text[pos:m.start()]))
        if m.group(1) is not None:
            out.append("\\fB\\%" + escape_code(m.group(1)) + "\\fP")
        elif m.group(2) is not None:
            out.append("\\fB" + escape_text(m.group(2)) + "\\fP")
        else:
            out.append("\\fI" + escape_text(m.group(3)) + "\\fP")
        pos = m.end()
    out.append(plain(text[pos:]))
    return "".join(out)


def move_nohyphen(line):
    """Moves every \\% (no hyphenation) to the start of its whitespace-delimited
    word: inside a word it would mark a break point instead."""
    def fix(m):
        word = m.group(0)
        if "\\%" not in word:
            return word
        return "\\%" + word.replace("\\%", "")
    return re.sub(r"\S+", fix, line)


def plain(text):
    text = escape_text(text)
    return XREF.sub(lambda m: "\\fB\\%%%s\\fP(%s)" % (m.group(1), m.group(2)), text)


# ---------------------------------------------------------------- parsing

def parse_front_matter(path, lines):
    if not lines or lines[0].strip() != "---":
        raise PageError("%s: must start with a '---' front matter block" % path)
    meta = {}
    for i in range(1, len(lines)):
        line = lines[i].rstrip("\n")
        if line.strip() == "---":
            return meta, lines[i + 1:]
        m = re.match(r"^([a-z]+):\s*(.*)$", line)
        if not m:
            raise PageError("%s:%d: bad front matter line: %r" % (path, i + 1, line))
        meta[m.group(1)] = m.group(2).strip()
    raise PageError("%s: unterminated front matter" % path)


def render_body(path, body):
    """Returns (roff lines, list of section headings, list of code blocks)."""
    out = []
    headings = []
    blocks = []
    para = []
    i = 0
    n = len(body)

    def flush_para():
        if para:
            out.append(".PP")
            for l in para:
                out.append(protect_line_start(move_nohyphen(inline(l))))
            para.clear()

    while i < n:
        line = body[i].rstrip("\n")
        stripped = line.strip()
        if stripped.startswith("```"):
            flush_para()
            lang = stripped[3:].strip()
            code = []
            i += 1
            while i < n and not body[i].strip().startswith("```"):
                code.append(body[i].rstrip("\n"))
                i += 1
            if i >= n:
                raise PageError("%s: unterminated code block" % path)
            i += 1
            blocks.append((headings[-1] if headings else "", lang, "\n".join(code)))
            out.append(".PP")
            out.append(".in +4n")
            out.append(".EX")
            for l in code:
                out.append(protect_line_start(escape_code(l)) if l else "")
            out.append(".EE")
            out.append(".in")
            continue
        if stripped == "":
            flush_para()
            i += 1
            continue
        if line.startswith("## "):
            flush_para()
            title = line[3:].strip()
            headings.append(title)
            out.append('.SH "%s"' % escape_text(title) if " " in title else ".SH %s" % escape_text(title))
            i += 1
            continue
        if line.startswith("### "):
            flush_para()
            out.append('.SS "%s"' % escape_text(line[4:].strip()))
            i += 1
            continue
        if line.startswith("- "):
            flush_para()
            item = [line[2:].strip()]
            i += 1
            while i < n and body[i].startswith("  ") and body[i].strip():
                item.append(body[i].strip())
                i += 1
            out.append(".IP \\(bu 2")
            for l in item:
                out.append(protect_line_start(move_nohyphen(inline(l))))
            continue
        # Definition list: a term line followed by ":   text" lines.
        if i + 1 < n and body[i + 1].startswith(":   "):
            flush_para()
            out.append(".TP")
            out.append(protect_line_start(move_nohyphen(inline(stripped))))
            i += 1
            first = True
            while i < n and (body[i].startswith(":   ") or (body[i].startswith("    ") and body[i].strip())):
                text = body[i][4:].strip()
                if body[i].startswith(":   ") and not first:
                    out.append(".IP")
                out.append(protect_line_start(move_nohyphen(inline(text))))
                first = False
                i += 1
            continue
        if line.startswith("#"):
            raise PageError("%s: unsupported heading level: %r" % (path, line))
        para.append(stripped)
        i += 1
    flush_para()
    return out, headings, blocks


def load_pages():
    pages = []
    seen = {}
    for fname in sorted(os.listdir(SRC)):
        if not fname.endswith(".md"):
            continue
        path = os.path.join(SRC, fname)
        with open(path, encoding="utf-8") as f:
            lines = f.readlines()
        meta, body = parse_front_matter(path, lines)
        for key in ("names", "summary"):
            if key not in meta:
                raise PageError("%s: front matter lacks '%s'" % (path, key))
        names = [x.strip() for x in meta["names"].split(",") if x.strip()]
        section = meta.get("section", "3")
        if fname != names[0] + ".md":
            raise PageError("%s: file name must be the first name, %s.md" % (path, names[0]))
        roff, headings, blocks = render_body(path, body)
        for name in names:
            if name in seen:
                raise PageError("%s: %s is already documented in %s" % (path, name, seen[name]))
            seen[name] = fname
        pages.append({
            "path": path,
            "names": names,
            "summary": meta["summary"],
            "section": section,
            "roff": roff,
            "headings": headings,
            "blocks": blocks,
        })
    return pages


def render_page(page, name, version, date):
    head = [
        '.\\" Generated by man/gen-man.py from %s; edit that file instead.'
        % os.path.relpath(page["path"], ROOT),
        '.\\" SPDX-License-Identifier: MIT OR Apache-2.0',
        '.TH %s %s %s "rsmodbus %s" "rsmodbus Manual"' % (escape_code(name), page["section"], date, version),
        # No hyphenation: identifiers must not be split across lines.
        ".nh",
        ".ad l",
        ".SH NAME",
        "%s \\- %s" % (", ".join(escape_code(n) for n in page["names"]), escape_text(page["summary"])),
    ]
    return "\n".join(head + page["roff"]) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(ROOT, "target", "man"))
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--blocks", metavar="DIR", help="write every code block to DIR/<page>.<n>.<lang> (for tests)")
    args = ap.parse_args()
    try:
        pages = load_pages()
    except PageError as e:
        print("gen-man: %s" % e, file=sys.stderr)
        return 1
    if args.list:
        for p in pages:
            for name in p["names"]:
                print(name, p["section"], os.path.relpath(p["path"], ROOT), "|".join(p["headings"]))
        return 0
    if args.blocks:
        os.makedirs(args.blocks, exist_ok=True)
        for p in pages:
            for k, (heading, lang, code) in enumerate(p["blocks"]):
                fname = "%s.%d.%s.%s" % (p["names"][0], k, heading.replace(" ", "_"), lang or "txt")
                with open(os.path.join(args.blocks, fname), "w", encoding="utf-8") as f:
                    f.write(code + "\n")
        return 0
    if args.check:
        return 0
    version = project_version()
    date = page_date()
    written = 0
    for p in pages:
        d = os.path.join(args.out, "man" + p["section"])
        os.makedirs(d, exist_ok=True)
        for name in p["names"]:
            text = render_page(p, name, version, date)
            target = os.path.join(d, "%s.%s" % (name, p["section"]))
            old = None
            if os.path.exists(target):
                with open(target, encoding="utf-8") as f:
                    old = f.read()
            if old != text:
                with open(target, "w", encoding="utf-8") as f:
                    f.write(text)
            written += 1
    # Remove pages whose source is gone.
    wanted = {"%s.%s" % (n, p["section"]) for p in pages for n in p["names"]}
    for sec in os.listdir(args.out) if os.path.isdir(args.out) else []:
        sd = os.path.join(args.out, sec)
        if sec.startswith("man") and os.path.isdir(sd):
            for f in os.listdir(sd):
                if f not in wanted:
                    os.remove(os.path.join(sd, f))
    print("gen-man: %d pages from %d sources in %s" % (written, len(pages), os.path.relpath(args.out, ROOT)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
