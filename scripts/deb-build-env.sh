# deb-build-env.sh: sourced; deb_build_env exports what dpkg-buildpackage and dh give
# debian/rules' commands and a cargo build reads: dpkg-buildflags' flags (ring's C code
# takes CFLAGS: its hardening) and SOURCE_DATE_EPOCH from debian/changelog. Used by
# scripts/build-pgo.sh --debian-flags and c-tests/suites/builds.sh, so that what they
# build is what the packages' build finds already built (build-pgo.sh's inputs take
# these variables in). Run from the project's root; needs dpkg-dev.
# SPDX-License-Identifier: MIT OR Apache-2.0
deb_build_env() {
    # With debian/rules' own additions to the flags (DEB_CFLAGS_MAINT_APPEND: ring's C
    # code at -O3), read from there.
    local append
    append=$(sed -n 's/^export DEB_CFLAGS_MAINT_APPEND *= *//p' debian/rules)
    eval "$(DEB_CFLAGS_MAINT_APPEND=$append dpkg-buildflags --export=sh)" || return 1
    SOURCE_DATE_EPOCH=$(dpkg-parsechangelog -STimestamp) || return 1
    export SOURCE_DATE_EPOCH
}
