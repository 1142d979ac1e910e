/*
 * Scenario "connect": TCP connection set-up. Run with the tcppi backend against
 * mbtest-server listening on "::" (dual stack):  scn-connect tcppi ::1 <port> <auxport>
 * <auxport> is a port nothing listens on (the runner checked it); this program also
 * uses it for a local "black hole" listener whose accept queue is full.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <stdlib.h>
#include <unistd.h>

#include "../common/mbtest.h"

int main(int argc, char **argv)
{
    modbus_t *ctx;
    const char *port, *aux;
    char got[128];
    int rc;

    if (argc < 5 || strcmp(argv[1], "tcppi") != 0) {
        fprintf(stderr, "usage: %s tcppi ::1 <port> <auxport>\n", argv[0]);
        return 1;
    }
    port = argv[3];
    aux = argv[4];

    mbt_section("tcp_pi to ::1");
    CHECK_PTR(ctx, modbus_new_tcp_pi("::1", port));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    mbt_read_two(ctx);
    /* connect twice: 3.1.6 closes nothing and opens a second socket */
    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));

    mbt_section("tcp_pi to 127.0.0.1 (v4 client, dual-stack server)");
    CHECK_PTR(ctx, modbus_new_tcp_pi("127.0.0.1", port));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    mbt_read_two(ctx);
    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));

    mbt_section("tcp_pi to localhost");
    CHECK_PTR(ctx, modbus_new_tcp_pi("localhost", port));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    mbt_read_two(ctx);
    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));

    mbt_section("tcp (IPv4 API) to the dual-stack server");
    CHECK_PTR(ctx, modbus_new_tcp("127.0.0.1", atoi(port)));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    mbt_read_two(ctx);
    CALL(modbus_close(ctx));
    /* reconnect the same context */
    CHECK(modbus_connect(ctx));
    mbt_read_two(ctx);
    CALL(modbus_close(ctx));
    CALL(modbus_free(ctx));

    mbt_section("connection refused");
    CHECK_PTR(ctx, modbus_new_tcp("127.0.0.1", atoi(aux)));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    CHECK(modbus_get_socket(ctx));
    CALL(modbus_free(ctx));
    CHECK_PTR(ctx, modbus_new_tcp_pi("::1", aux));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    CALL(modbus_free(ctx));
    CHECK_PTR(ctx, modbus_new_tcp_pi("127.0.0.1", aux));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    CALL(modbus_free(ctx));

    mbt_section("getaddrinfo failure");
    CHECK_PTR(ctx, modbus_new_tcp_pi("::1", "no-such-service-name"));
    CHECK(modbus_set_debug(ctx, TRUE));
    CHECK(modbus_connect(ctx));
    CALL(modbus_free(ctx));

    mbt_section("invalid IPv4 string");
    CHECK_PTR(ctx, modbus_new_tcp("999.1.2.3", atoi(aux)));
    CHECK(modbus_set_debug(ctx, TRUE));
    {
        int err;
        char r[64];
        DIFF_BLOCK_RC(NULL, "invalid-ip-inet-pton", rc, err, modbus_connect(ctx));
        snprintf(got, sizeof(got), "connect(\"999.1.2.3\"): %s",
                 rc == -1 ? "rc=-1" : mbt_fmt_rc(r, sizeof(r), rc, err));
        mbt_diff_value("invalid-ip-inet-pton", got, "connect(\"999.1.2.3\"): rc=-1",
                       "connect(\"999.1.2.3\"): rc=-1");
    }
    CALL(modbus_free(ctx));

    mbt_section("connect timeout (black hole: full accept queue)");
    {
        int lfd, bound = 0, fill[4], i;
        lfd = mbt_tcp_listen(atoi(aux), 0, &bound);
        if (lfd < 0 || mbt_fill_backlog(bound, fill, 4) != 0) {
            printf("cannot set up the black hole listener\n");
        } else {
            int err;
            char r[64];
            CHECK_PTR(ctx, modbus_new_tcp("127.0.0.1", atoi(aux)));
            CHECK(modbus_set_response_timeout(ctx, 0, 300000));
            CHECK(modbus_set_debug(ctx, TRUE));
            DIFF_BLOCK_RC(NULL, "connect-timeout-errno", rc, err, modbus_connect(ctx));
            snprintf(got, sizeof(got), "connect(black hole): %s", mbt_fmt_rc(r, sizeof(r), rc, err));
            mbt_diff_value("connect-timeout-errno", got, "connect(black hole): rc=-1 errno=EINPROGRESS",
                           "connect(black hole): rc=-1 errno=ETIMEDOUT");
            CHECK(modbus_get_socket(ctx));
            CALL(modbus_free(ctx));
            for (i = 0; i < 4; i++) {
                close(fill[i]);
            }
            close(lfd);
        }
    }

    printf("END\n");
    return 0;
}
