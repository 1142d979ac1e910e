# extract-tags.awk: prints "<name>\t<line>" for every line covered by a DIFF-OK tag or
# inside a DIFF-OK-BEGIN/END block, so that the runner can tell which allowed
# differences were actually observed (raw content differs between the two runs).
#
# SPDX-License-Identifier: MIT OR Apache-2.0
function handle(line,    rest) {
    if (block != "") {
        if (line == "DIFF-OK-END " block) { block = ""; return }
        print block "\t" line
        return
    }
    if (line ~ /^DIFF-OK-BEGIN /) { block = substr(line, 15); return }
    if (line ~ /^DIFF-OK [^ :]+: /) {
        rest = substr(line, 9)
        print substr(rest, 1, index(rest, ":") - 1) "\t" line
    }
}
{
    line = $0
    while ((p = index(substr(line, 2), "DIFF-OK")) > 0) {
        handle(substr(line, 1, p))
        line = substr(line, p + 1)
    }
    handle(line)
}
