/*
 * tls-test: the client side of the Modbus/TCP Security tests (scripts/run-tls-tests.sh),
 * against examples/tls-server.c and its role policy (Operator: everything; Reader:
 * reads; anything else: refused with exception 01).
 *
 *   tls-test CERTDIR HOST PORT SCENARIO [N]
 *
 * Scenarios (each prints LIBINFO, then "PASS ..." or "FAIL ..." lines; exit 0 when
 * every check passed):
 *   operator   reads registers 0-4 (1000..1004 or what a write left), writes one and
 *              reads it back; the server's certificate has no role (ENOENT)
 *   reader     reads; a write gets EMBXILFUN and changes nothing
 *   norole     a read gets EMBXILFUN
 *   nocert     no client certificate: EMBTLSNOCERT (at connect or at the first request:
 *              with TLS 1.3 the client's handshake ends before the server's verdict)
 *   rogue      a client of another CA: EMBTLSUNKNOWNCA
 *   expired    an expired client certificate: EMBTLSEXPIRED
 *   wrongname  the server's certificate is for another name: modbus_connect fails
 *              with EMBTLSNAME
 *   noca       no CA set: modbus_connect fails with EMBTLSCONFIG
 *   resume     connects twice with the same context; the debug trace of the second
 *              handshake says "resumed"
 *   many N     N clients at once (processes), each writing and reading back its own
 *              register 10 + i
 *   reconnect  cut: connect, read, then the next connect after a peer's reset works
 *   halfrecord against c-tests/tls/cut.py's server, which sends half of the answer's
 *              record and closes: the read fails (ECONNRESET, as when a TCP peer goes
 *              away) at once, not at the timeout; the next connect and read work
 *   password   keys encrypted with a password (make-certs.sh): without it or with a
 *              wrong one EMBTLSPASSWORD; with it (PBES2 with PBKDF2 or scrypt) the
 *              client connects and writes as Operator; PBES1 and OpenSSL's older
 *              encrypted PEM are refused with EINVAL; a password given for a key that
 *              is not encrypted is not used
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

int print_loaded_libmodbus(void);

static int failures;

static void check(int ok, const char *what, const char *detail)
{
    printf("%s %s%s%s\n", ok ? "PASS" : "FAIL", what, detail ? ": " : "", detail ? detail : "");
    if (!ok)
        failures++;
}

static const char *dir;

static char *path(const char *name, const char *ext)
{
    static char buf[4][512];
    static int i;
    char *p = buf[i++ % 4];
    snprintf(p, 512, "%s/%s.%s", dir, name, ext);
    return p;
}

/* A TLS client context with the client certificate `who` (NULL: none). */
static modbus_t *client(const char *host, const char *port, const char *who, int with_ca)
{
    modbus_t *ctx = modbus_new_tcp_tls_pi(host, port);
    if (ctx == NULL) {
        check(0, "modbus_new_tcp_tls_pi", modbus_strerror(errno));
        exit(1);
    }
    if (with_ca && modbus_set_tls_ca(ctx, path("ca", "pem")) == -1)
        check(0, "modbus_set_tls_ca", modbus_strerror(errno));
    if (who != NULL && modbus_set_tls_certificate(ctx, path(who, "pem"), path(who, "key")) == -1)
        check(0, "modbus_set_tls_certificate", modbus_strerror(errno));
    return ctx;
}

/* Connects and reads: the errno of the first failure, 0 if both worked. */
static int connect_and_read(modbus_t *ctx, uint16_t *regs)
{
    if (modbus_connect(ctx) == -1)
        return errno;
    if (modbus_read_registers(ctx, 0, 5, regs) != 5)
        return errno;
    return 0;
}

static void expect_refusal(const char *host, const char *port, const char *who, int want, const char *what)
{
    uint16_t regs[5];
    modbus_t *ctx = client(host, port, who, 1);
    int e = connect_and_read(ctx, regs);
    char detail[200];
    snprintf(detail, sizeof detail, "errno %d (%s), want %d (%s)", e, e ? modbus_strerror(e) : "none", want,
             modbus_strerror(want));
    check(e == want, what, detail);
    modbus_close(ctx);
    modbus_free(ctx);
}

int main(int argc, char *argv[])
{
    if (argc < 5) {
        fprintf(stderr, "usage: %s CERTDIR HOST PORT SCENARIO [N]\n", argv[0]);
        return 2;
    }
    print_loaded_libmodbus();
    dir = argv[1];
    const char *host = argv[2], *port = argv[3], *scenario = argv[4];
    uint16_t regs[5];
    char detail[256];

    if (strcmp(scenario, "operator") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        int e = connect_and_read(ctx, regs);
        check(e == 0, "operator: connect and read 5 registers", e ? modbus_strerror(e) : NULL);
        snprintf(detail, sizeof detail, "%u %u %u %u %u", regs[0], regs[1], regs[2], regs[3], regs[4]);
        check(e == 0 && regs[1] == 1001 && regs[4] == 1004, "operator: values", detail);
        check(modbus_write_register(ctx, 3, 4242) == 1, "operator: write allowed", modbus_strerror(errno));
        check(modbus_read_registers(ctx, 3, 1, regs) == 1 && regs[0] == 4242, "operator: written value read back",
              NULL);
        char role[64];
        int rc = modbus_get_tls_peer_role(ctx, role, sizeof role);
        check(rc == -1 && errno == ENOENT, "operator: the server's certificate has no role (ENOENT)", NULL);
        check(modbus_write_register(ctx, 3, 1003) == 1, "operator: value restored", NULL);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "reader") == 0) {
        modbus_t *ctx = client(host, port, "reader", 1);
        int e = connect_and_read(ctx, regs);
        check(e == 0, "reader: connect and read", e ? modbus_strerror(e) : NULL);
        int rc = modbus_write_register(ctx, 2, 7);
        snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
        check(rc == -1 && errno == EMBXILFUN, "reader: write refused with exception 01", detail);
        uint16_t before = regs[2];
        check(modbus_read_registers(ctx, 2, 1, regs) == 1 && regs[0] == before, "reader: register unchanged", NULL);
        rc = modbus_write_registers(ctx, 0, 2, regs);
        check(rc == -1 && errno == EMBXILFUN, "reader: FC 16 refused too", NULL);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "norole") == 0) {
        modbus_t *ctx = client(host, port, "norole", 1);
        int e = connect_and_read(ctx, regs);
        snprintf(detail, sizeof detail, "errno %d (%s)", e, modbus_strerror(e));
        check(e == EMBXILFUN, "norole: a read is refused with exception 01", detail);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "nocert") == 0) {
        expect_refusal(host, port, NULL, EMBTLSNOCERT, "nocert: refused, EMBTLSNOCERT");
    } else if (strcmp(scenario, "rogue") == 0) {
        expect_refusal(host, port, "rogue", EMBTLSUNKNOWNCA, "rogue: refused, EMBTLSUNKNOWNCA");
    } else if (strcmp(scenario, "expired") == 0) {
        expect_refusal(host, port, "expired", EMBTLSEXPIRED, "expired: refused, EMBTLSEXPIRED");
    } else if (strcmp(scenario, "wrongname") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        int rc = modbus_connect(ctx);
        snprintf(detail, sizeof detail, "rc %d errno %d (%s), socket %d", rc, errno, modbus_strerror(errno),
                 modbus_get_socket(ctx));
        check(rc == -1 && errno == EMBTLSNAME && modbus_get_socket(ctx) == -1,
              "wrongname: connect fails with EMBTLSNAME, no socket left", detail);
        modbus_free(ctx);
    } else if (strcmp(scenario, "noca") == 0) {
        modbus_t *ctx = client(host, port, "operator", 0);
        int rc = modbus_connect(ctx);
        check(rc == -1 && errno == EMBTLSCONFIG, "noca: connect fails with EMBTLSCONFIG", modbus_strerror(errno));
        modbus_free(ctx);
    } else if (strcmp(scenario, "resume") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        modbus_set_debug(ctx, TRUE);
        int e1 = connect_and_read(ctx, regs);
        modbus_close(ctx);
        int e2 = connect_and_read(ctx, regs);
        modbus_close(ctx);
        modbus_free(ctx);
        fflush(stdout);
        check(e1 == 0 && e2 == 0, "resume: two connections on one context", NULL);
    } else if (strcmp(scenario, "many") == 0) {
        int n = argc > 5 ? atoi(argv[5]) : 64;
        pid_t pids[256];
        fflush(stdout);
        for (int i = 0; i < n && i < 256; i++) {
            pids[i] = fork();
            if (pids[i] == 0) {
                uint16_t v = 0;
                modbus_t *ctx = client(host, port, "operator", 1);
                int ok = connect_and_read(ctx, regs) == 0 && modbus_write_register(ctx, 10 + i, 5000 + i) == 1 &&
                         modbus_read_registers(ctx, 10 + i, 1, &v) == 1 && v == 5000 + i;
                modbus_close(ctx);
                modbus_free(ctx);
                _exit(ok ? 0 : 1);
            }
        }
        int good = 0;
        for (int i = 0; i < n && i < 256; i++) {
            int st;
            if (waitpid(pids[i], &st, 0) == pids[i] && WIFEXITED(st) && WEXITSTATUS(st) == 0)
                good++;
        }
        snprintf(detail, sizeof detail, "%d of %d clients right", good, n);
        check(good == n, "many: every client reads back its own register", detail);
    } else if (strcmp(scenario, "reconnect") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        int e = connect_and_read(ctx, regs);
        check(e == 0, "reconnect: first connection", e ? modbus_strerror(e) : NULL);
        /* The peer resets the connection under us (the test's server is killed and
         * restarted by the caller between the two halves: see run-tls-tests.sh). */
        printf("WAITING\n");
        fflush(stdout);
        char line[16];
        if (fgets(line, sizeof line, stdin) == NULL)
            return 2;
        int rc = modbus_read_registers(ctx, 0, 5, regs);
        snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
        check(rc == -1, "reconnect: a read on the cut connection fails", detail);
        modbus_close(ctx);
        e = connect_and_read(ctx, regs);
        check(e == 0, "reconnect: the next connect works", e ? modbus_strerror(e) : NULL);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "halfrecord") == 0) {
        modbus_t *ctx = client(host, port, "operator", 1);
        modbus_set_response_timeout(ctx, 5, 0);
        int rc = modbus_connect(ctx);
        check(rc == 0, "halfrecord: connect", rc ? modbus_strerror(errno) : NULL);
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        rc = modbus_read_registers(ctx, 5, 1, regs);
        int e = errno;
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double took = (double)(t1.tv_sec - t0.tv_sec) + (double)(t1.tv_nsec - t0.tv_nsec) / 1e9;
        snprintf(detail, sizeof detail, "rc %d errno %d (%s) after %.2f s", rc, e, modbus_strerror(e), took);
        check(rc == -1 && e == ECONNRESET && took < 4.0,
              "halfrecord: a read cut in the middle of the answer's record fails with ECONNRESET, before the timeout",
              detail);
        modbus_close(ctx);
        rc = modbus_connect(ctx) == 0 && modbus_read_registers(ctx, 5, 1, regs) == 1 ? 0 : errno;
        snprintf(detail, sizeof detail, "%s, value %u", rc ? modbus_strerror(rc) : "ok", regs[0]);
        check(rc == 0 && regs[0] == 1005, "halfrecord: the next connect and read work", detail);
        modbus_close(ctx);
        modbus_free(ctx);
    } else if (strcmp(scenario, "password") == 0) {
        static const struct {
            const char *key, *password, *what;
            int want; /* 0: accepted, else the errno */
        } keys[] = {
            {"operator-aes", NULL, "PBES2/AES key without a password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-aes", "wrong", "PBES2/AES key, wrong password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-aes", "", "PBES2/AES key, empty password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-scrypt", "Secret", "scrypt key, wrong password: EMBTLSPASSWORD", EMBTLSPASSWORD},
            {"operator-pbes1", "secret", "PBES1 (3DES) key: EINVAL, not supported", EINVAL},
            {"operator-legacy", "secret", "OpenSSL's older encrypted PEM: EINVAL, not supported", EINVAL},
            {"operator", "unused", "a key that is not encrypted, with a password: accepted", 0},
            {"operator-aes", "secret", "PBES2/AES key, right password: accepted", 0},
            {"operator-scrypt", "secret", "scrypt key, right password: accepted", 0},
        };
        for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++) {
            modbus_t *ctx = client(host, port, NULL, 1);
            errno = 0;
            int rc = modbus_set_tls_certificate_with_password(ctx, path("operator", "pem"), path(keys[i].key, "key"),
                                                              keys[i].password);
            int e = errno;
            snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, e, modbus_strerror(e));
            check(keys[i].want ? rc == -1 && e == keys[i].want : rc == 0, keys[i].what, detail);
            if (keys[i].want == 0 && rc == 0) {
                /* The decrypted key signs the handshake: the server accepts the Operator. */
                int ce = connect_and_read(ctx, regs);
                snprintf(detail, sizeof detail, "%s with %s", ce ? modbus_strerror(ce) : "ok", keys[i].key);
                check(ce == 0 && modbus_write_register(ctx, 3, 1003) == 1, "password: connect, read and write",
                      detail);
                modbus_close(ctx);
            }
            modbus_free(ctx);
        }
        /* The plain call on an encrypted key says a password is needed. */
        modbus_t *ctx = client(host, port, NULL, 1);
        int rc = modbus_set_tls_certificate(ctx, path("operator", "pem"), path("operator-aes", "key"));
        snprintf(detail, sizeof detail, "rc %d errno %d (%s)", rc, errno, modbus_strerror(errno));
        check(rc == -1 && errno == EMBTLSPASSWORD &&
                  strstr(modbus_strerror(EMBTLSPASSWORD), "password") != NULL,
              "modbus_set_tls_certificate on an encrypted key: EMBTLSPASSWORD, named by modbus_strerror", detail);
        modbus_free(ctx);
    } else {
        fprintf(stderr, "unknown scenario %s\n", scenario);
        return 2;
    }
    return failures ? 1 : 0;
}
