#!/usr/bin/env python3
"""abi-witness.py: writes the C "witness" of the public headers' ABI to stdout.

The Rust library's own debug information describes Rust types, not the C headers'.
The witness is a C file that, compiled with -g into a shared object, makes the
compiler record in DWARF what the headers declare, so that libabigail's abidw can
dump it and abidiff compare it (scripts/abi-update.sh, c-tests/suites/abi-check.sh):

  fn_NAME      one pointer per function row of abi/exports.txt, of the header's type
               (`__typeof__(NAME) *`): its return and parameter types, and through
               them every type they reach;
  obj_NAME     the same for the exported objects (libmodbus_version_*);
  type_NAME    one pointer per typedef the headers declare (structs, enums, callback
               types...): every member, its type and offset, every enumerator;
  tag_KIND_TAG one pointer per struct/union/enum tag the headers declare;
  const_NAME   one pointer per integer constant, to an enum whose one enumerator has
               its value: every object-like macro of the headers whose value is an
               integer constant expression (the compiler decides), and every
               enumerator of an anonymous enum.

The names come from the headers themselves (the preprocessor's output, lines of
the include directory only), so a new typedef or macro is covered without editing
this script. The witness is generated, never committed: abi/headers.abi is.

Usage: scripts/abi-witness.py INCLUDE_DIR EXPORTS_TXT [CC] > witness.c
SPDX-License-Identifier: MIT OR Apache-2.0
"""

import os
import re
import subprocess
import sys

HEADERS = ["modbus.h", "modbus-rtu.h", "modbus-tcp.h", "modbus-tls.h", "modbus-version.h"]
TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*|0[xX][0-9A-Fa-f]+|\d+|\"(?:\\.|[^\"\\])*\"|'(?:\\.|[^'\\])*'|\S")
IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*$")
KEYWORDS = {
    "struct", "union", "enum", "typedef", "const", "volatile", "unsigned", "signed",
    "int", "char", "short", "long", "void", "float", "double", "extern", "static",
    "restrict", "__restrict", "_Bool", "inline",
}
# An integer constant expression: numbers, identifiers, operators, parentheses.
INTEGER_BODY = re.compile(r"^[\sA-Za-z0-9_()+\-*/%<>|&~^!]+$")


def die(msg):
    sys.stderr.write("abi-witness.py: %s\n" % msg)
    sys.exit(1)


def preprocess(cc, include):
    src = "".join("#include <%s>\n" % h for h in HEADERS)
    try:
        out = subprocess.run(
            [cc, "-E", "-dD", "-std=gnu11", "-I", include, "-x", "c", "-"],
            input=src, capture_output=True, text=True, check=True,
        ).stdout
    except subprocess.CalledProcessError as e:
        die("the headers do not preprocess:\n" + e.stderr)
    inc = os.path.realpath(include)
    code, macros, current = [], [], ""
    marker = re.compile(r'^# \d+ "([^"]*)"')
    for line in out.splitlines():
        m = marker.match(line)
        if m:
            current = os.path.realpath(m.group(1)) if not m.group(1).startswith("<") else ""
            continue
        if os.path.dirname(current) != inc:
            continue
        if line.startswith("#define "):
            macros.append(line[len("#define "):])
        elif not line.startswith("#"):
            code.append(line)
    return " ".join(code), macros


def declarations(code):
    """The typedef names, the tags and the anonymous enums' enumerators of `code`."""
    toks = TOKEN.findall(code)
    typedefs, tags, enumerators = [], [], []
    i, depth = 0, 0
    while i < len(toks):
        t = toks[i]
        if t in ("struct", "union", "enum") and i + 1 < len(toks):
            nxt = toks[i + 1]
            if IDENT.match(nxt) and nxt not in KEYWORDS:
                if (t, nxt) not in tags:
                    tags.append((t, nxt))
            elif t == "enum" and nxt == "{":
                # Anonymous enum: its enumerators are constants; a typedef'd one is a
                # type of its own and is recorded as such (see below).
                j, names, d = i + 2, [], 1
                while j < len(toks) and d > 0:
                    if toks[j] in "{([":
                        d += 1
                    elif toks[j] in "})]":
                        d -= 1
                    elif d == 1 and IDENT.match(toks[j]) and toks[j + 1] in ("=", ",", "}"):
                        if toks[j - 1] in ("{", ","):
                            names.append(toks[j])
                    j += 1
                is_typedef = any(toks[k] == "typedef" for k in range(max(0, i - 3), i))
                if not is_typedef:
                    enumerators.extend(names)
        if t == "typedef" and depth == 0:
            j, d, last, fnptr = i + 1, 0, None, None
            while j < len(toks) and not (d == 0 and toks[j] == ";"):
                if toks[j] in "{([":
                    if toks[j] == "(" and d == 0 and fnptr is None and toks[j + 1] == "*" and IDENT.match(toks[j + 2]):
                        fnptr = toks[j + 2]
                    d += 1
                elif toks[j] in "})]":
                    d -= 1
                elif d == 0 and IDENT.match(toks[j]) and toks[j] not in KEYWORDS:
                    last = toks[j]
                j += 1
            name = fnptr or last
            if name is None:
                die("cannot find the name of a typedef near: " + " ".join(toks[i:j + 1]))
            if name not in typedefs:
                typedefs.append(name)
        if t in "{([":
            depth += 1
        elif t in "})]":
            depth -= 1
        i += 1
    return typedefs, tags, enumerators


def integer_macros(macros):
    names = []
    for m in macros:
        name, _, body = m.partition(" ")
        if "(" in name:  # function-like
            continue
        body = body.strip()
        if not body or not INTEGER_BODY.match(body):
            continue
        if not re.search(r"\d", body) and all(
            w in KEYWORDS or w.startswith("__") for w in re.findall(r"[A-Za-z_]\w*", body)
        ):
            continue  # e.g. an attribute or a keyword, not a number
        if name not in names:
            names.append(name)
    return names


def integer_constants(cc, include, names):
    """The macros of `names` that are integer constant expressions: the compiler says
    which are not (an alias of a function, a type...), and those are left out."""
    names = list(names)
    for _ in range(len(names) + 1):
        lines = ["#include <%s>" % h for h in HEADERS]
        first = len(lines) + 1
        lines += ["enum abi_probe_%s { probe_%s = (%s) };" % (c, c, c) for c in names]
        r = subprocess.run(
            [cc, "-std=gnu11", "-fsyntax-only", "-I", include, "-x", "c", "-"],
            input="\n".join(lines) + "\n", capture_output=True, text=True,
        )
        if r.returncode == 0:
            return names
        bad = {int(n) - first for n in re.findall(r"^<stdin>:(\d+):\d+: error", r.stderr, re.M)}
        bad = {i for i in bad if 0 <= i < len(names)}
        if not bad:
            die("the headers do not compile:\n" + r.stderr)
        names = [c for i, c in enumerate(names) if i not in bad]
    return names


def export_rows(path):
    rows = []
    with open(path) as f:
        for line in f:
            if re.match(r"^\s*(#|$)", line):
                continue
            rows.append(line.split("|")[0].strip())
    return rows


def main():
    if len(sys.argv) not in (3, 4):
        die("usage: abi-witness.py INCLUDE_DIR EXPORTS_TXT [CC]")
    include, exports = sys.argv[1], sys.argv[2]
    cc = sys.argv[3] if len(sys.argv) == 4 else os.environ.get("CC", "gcc")
    code, macros = preprocess(cc, include)
    typedefs, tags, enumerators = declarations(code)
    consts = integer_constants(cc, include, integer_macros(macros)) + enumerators

    out = [
        "/* The ABI witness of the public headers: generated by scripts/abi-witness.py",
        " * from %s and %s; compiled with -g for abidw. Do not edit. */" % (include, exports),
        "",
    ]
    out += ["#include <%s>" % h for h in HEADERS]
    out += ["", "/* The exports (rows of %s), with the header's types. */" % exports]
    for name in export_rows(exports):
        prefix = "obj" if name.startswith("libmodbus_version_") else "fn"
        out.append("__typeof__(%s) *%s_%s = 0;" % (name, prefix, name))
    out += ["", "/* Every typedef of the headers. */"]
    for name in typedefs:
        out.append("%s *type_%s = 0;" % (name, name))
    out += ["", "/* Every struct, union and enum tag of the headers. */"]
    for kind, tag in tags:
        out.append("%s %s *tag_%s_%s = 0;" % (kind, tag, kind, tag))
    out += ["", "/* The integer constants (object-like macros, anonymous enumerators): each the",
            " * one enumerator of an enum of its own, so that abidiff reports a new or removed",
            " * one as a variable and a changed value as an enumerator change. */"]
    for c in consts:
        out.append("enum abi_const_%s { value_%s = (%s) } *const_%s = 0;" % (c, c, c, c))
    out.append("")
    sys.stdout.write("\n".join(out))


if __name__ == "__main__":
    main()
