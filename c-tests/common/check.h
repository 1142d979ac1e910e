/*
 * check.h: the one way a C test program of c-tests/ counts and reports its checks.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 *
 * Each check prints one line on stdout, flushed at once (so that a crash loses none):
 *
 *   ok   - <prefix><what>
 *   FAIL - <prefix><what>  [file.c:line]
 *
 * and the program ends with chk_summary(), which prints the line the runners add to
 * their totals and returns the exit status:
 *
 *   <prefix>N passed, M failed
 *
 * c-tests/common/testlib.sh prints its own checks in the same form ("ok   - " / "FAIL - ").
 * The prefix is empty unless the program sets one (chk_set_prefix); the summary line
 * is only counted by the runners when the prefix is empty then.
 *
 * Header only: the counters are static, one pair per translation unit. A program
 * made of several files counts in one of them (c-tests/interop/interop.c does it for
 * the interoperability programs). A forked child counts on its own copy.
 *
 * This is not mbtest.h's CHECK()/CHECK_RC(): those print a call's return value and
 * errno for the differential comparison (the verdict is the diff against Debian's
 * libmodbus), they count nothing. The names here do not clash with them.
 */
#ifndef MBT_CHECK_H
#define MBT_CHECK_H

#include <stdarg.h>
#include <stdio.h>

struct chk_state {
    int passed;
    int failed;
    const char *prefix;
};

static inline struct chk_state *chk_state(void)
{
    static struct chk_state s = {0, 0, ""};
    return &s;
}

/* One check: counts it and prints its line; `where` ("file.c:123") is shown on failure
 * only (NULL: not shown). Returns cond (0 or 1). */
__attribute__((format(printf, 3, 0))) static inline int chk_vreport(int cond, const char *where, const char *fmt,
                                                                    va_list ap)
{
    struct chk_state *s = chk_state();
    cond = cond != 0;
    if (cond) {
        s->passed++;
    } else {
        s->failed++;
    }
    printf("%s%s", cond ? "ok   - " : "FAIL - ", s->prefix);
    vprintf(fmt, ap);
    if (!cond && where != NULL) {
        printf("  [%s]", where);
    }
    printf("\n");
    fflush(stdout);
    return cond;
}

__attribute__((format(printf, 3, 4))) static inline int chk_report(int cond, const char *where, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    cond = chk_vreport(cond, where, fmt, ap);
    va_end(ap);
    return cond;
}

#define CHK_STR_(x) #x
#define CHK_STR(x) CHK_STR_(x)
#define CHK_WHERE __FILE__ ":" CHK_STR(__LINE__)

/* EXPECT(cond, fmt, ...): the check macro. Passes when cond is true; the line names
 * the check with the printf-style format. Evaluates to cond (0 or 1). */
#define EXPECT(cond, ...) chk_report((cond) ? 1 : 0, CHK_WHERE, __VA_ARGS__)

/* EXPECT_DETAIL(cond, what, detail): "<what>: <detail>", or "<what>" when detail is
 * NULL (detail is shown on passing lines too). Each argument is evaluated once. */
static inline int chk_detail(int cond, const char *where, const char *what, const char *detail)
{
    return chk_report(cond, where, "%s%s%s", what, detail != NULL ? ": " : "", detail != NULL ? detail : "");
}
#define EXPECT_DETAIL(cond, what, detail) chk_detail((cond) ? 1 : 0, CHK_WHERE, (what), (detail))

/* Prefix of every following line (e.g. "tcp: "); NULL or "" for none. The string must
 * outlive its use. */
static inline void chk_set_prefix(const char *prefix)
{
    chk_state()->prefix = prefix != NULL ? prefix : "";
}

static inline int chk_passed(void)
{
    return chk_state()->passed;
}

static inline int chk_failed(void)
{
    return chk_state()->failed;
}

/* Prints "<prefix>N passed, M failed"; returns the program's exit status: 0 when
 * something passed and nothing failed, else 1 (a run without any check fails). */
static inline int chk_summary(void)
{
    struct chk_state *s = chk_state();
    printf("%s%d passed, %d failed\n", s->prefix, s->passed, s->failed);
    fflush(stdout);
    return s->failed == 0 && s->passed > 0 ? 0 : 1;
}

#endif /* MBT_CHECK_H */
