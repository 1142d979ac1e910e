# normalize.awk: masks the named, allowed differences in one captured output stream.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
#
# usage: awk -v allowed="name1 name2 ..." -f normalize.awk FILE
#   "DIFF-OK <name>: text"          -> "DIFF-OK <name>: (masked)"     if <name> allowed
#   "DIFF-OK-BEGIN <name>" .. "DIFF-OK-END <name>"
#                                   -> "DIFF-OK-BLOCK <name> (masked)" if <name> allowed
# Anything else, and every tag whose name is not allowed, is passed through unchanged,
# so that it still shows up in the comparison. A marker that follows a partial line
# (e.g. a receive trace cut by a timeout) is split onto its own line first.
BEGIN {
    n = split(allowed, names, " ")
    for (i = 1; i <= n; i++) ok[names[i]] = 1
    skipping = ""
}
function handle(line,    name, rest) {
    if (skipping != "") {
        if (line == "DIFF-OK-END " skipping) skipping = ""
        return
    }
    if (line ~ /^DIFF-OK-BEGIN /) {
        name = substr(line, 15)
        if (name in ok) {
            print "DIFF-OK-BLOCK " name " (masked)"
            skipping = name
            return
        }
    } else if (line ~ /^DIFF-OK [^ :]+: /) {
        rest = substr(line, 9)
        name = substr(rest, 1, index(rest, ":") - 1)
        if (name in ok) {
            print "DIFF-OK " name ": (masked)"
            return
        }
    }
    print line
}
{
    line = $0
    while ((p = index(substr(line, 2), "DIFF-OK")) > 0) {
        handle(substr(line, 1, p))
        line = substr(line, p + 1)
    }
    handle(line)
}
END {
    if (skipping != "") print "UNTERMINATED DIFF-OK-BLOCK " skipping
}
