/*
 * runner-server.c: a server that runs itself (modbus_server_new(3)), for
 * c-tests/suites/runner.sh and the examples' benchmarks.
 *
 *   runner-server tcp <port> [options]
 *   runner-server rtutcp <port> [options]
 *   runner-server tls <port> <cert> <key> <ca> [options]
 *   runner-server rtu <device> [options]
 *   runner-server udp <port> [options]
 *
 * options:
 *   --callbacks    answer through callbacks (units 1, 2 and 7, each its own data;
 *                  silence for the others on RTU, exception 0B on TCP) instead of
 *                  a mapping (every unit, one table)
 *   --idle MS      the idle timeout (default: the library's)
 *   --max N        at most N clients at once (default 1000)
 *   --nofile N     raise the descriptor limit to N first (to the hard limit at most,
 *                  when it cannot be raised)
 *   --status V     configure the context beyond libmodbus first: FC 07 (read exception
 *                  status) answers V (modbus_set_exception_status)
 *   --later        answer every request later (a gateway's way): a `raw` callback
 *                  that returns MODBUS_REPLY_LATER, and a thread that answers with
 *                  modbus_server_answer() after up to 50 ms, the requests of a burst in
 *                  reverse order: FC 03 and 04 from the mapping, FC 06 echoed, a read of
 *                  register 999 not at all (MODBUS_REPLY_NONE), anything else with
 *                  exception 01
 *   --bench        the benchmarks' data (benches/mb-server.c's: holding register i
 *                  holds 3 * i)
 *   --poll         run in steps of modbus_server_run(s, 0) after poll() on
 *                  modbus_server_get_fd(s), instead of modbus_server_run(s, -1)
 *
 * With port 0 (TCP), the program listens itself (modbus_tcp_listen on an ephemeral
 * port, given to the server with modbus_set_socket) and prints READY <port>.
 *
 * Register i of unit u holds 1000 * k + i (k: 0 for the mapping, the unit's index
 * + 1 for callbacks); coil i is i % 3 == 0. Writing 0xDEAD to holding register 999
 * stops the server from the callback (callbacks only). SIGTERM or SIGINT stop it
 * from a signal handler. It prints READY once it listens, and at the end the
 * requests it answered, then exits 0.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/mbtest.h"

#define NB 1000
#define UNITS 3
static const int UNIT_IDS[UNITS] = {1, 2, 7};

static modbus_server_t *server;
static modbus_mapping_t *maps[UNITS + 1];
static volatile sig_atomic_t signalled;

static void on_signal(int sig)
{
    (void) sig;
    signalled = 1;
    modbus_server_stop(server);
}

static int unit_index(int unit)
{
    int i;
    for (i = 0; i < UNITS; i++) {
        if (UNIT_IDS[i] == unit) {
            return i;
        }
    }
    return -1;
}

static modbus_mapping_t *map_of(const modbus_request_info_t *ri)
{
    int i = unit_index(ri->unit_id);
    return i < 0 ? NULL : maps[i + 1];
}

static int cb_accept(const modbus_request_info_t *ri, int unit, void *user_data)
{
    (void) ri;
    (void) user_data;
    return unit_index(unit) >= 0;
}

static int cb_read_bits(const modbus_request_info_t *ri, int addr, int nb, uint8_t *dest, void *ud)
{
    modbus_mapping_t *m = map_of(ri);
    uint8_t *t = ri->function == MODBUS_FC_READ_DISCRETE_INPUTS ? m->tab_input_bits : m->tab_bits;
    (void) ud;
    if (addr + nb > NB) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    memcpy(dest, t + addr, (size_t) nb);
    return 0;
}

static int cb_read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest, void *ud)
{
    modbus_mapping_t *m = map_of(ri);
    uint16_t *t = ri->function == MODBUS_FC_READ_INPUT_REGISTERS ? m->tab_input_registers : m->tab_registers;
    (void) ud;
    if (addr + nb > NB) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    memcpy(dest, t + addr, (size_t) nb * 2);
    return 0;
}

static int cb_write_bits(const modbus_request_info_t *ri, int addr, int nb, const uint8_t *src, void *ud)
{
    int i;
    (void) ud;
    if (addr + nb > NB) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    /* A broadcast (unit 0) writes every unit's table. */
    for (i = 0; i < UNITS; i++) {
        if (ri->unit_id == 0 || ri->unit_id == UNIT_IDS[i]) {
            memcpy(maps[i + 1]->tab_bits + addr, src, (size_t) nb);
        }
    }
    return 0;
}

static int cb_write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src, void *ud)
{
    int i;
    (void) ud;
    if (addr + nb > NB) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    if (addr <= 999 && addr + nb > 999 && src[999 - addr] == 0xDEAD) {
        printf("stop asked by a client\n");
        modbus_server_stop(server);
    }
    for (i = 0; i < UNITS; i++) {
        if (ri->unit_id == 0 || ri->unit_id == UNIT_IDS[i]) {
            memcpy(maps[i + 1]->tab_registers + addr, src, (size_t) nb * 2);
        }
    }
    return 0;
}

/* --later: the requests waiting for their answer, and the thread that answers. */
#define LATER_MAX 256
static struct {
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int id[LATER_MAX];
    uint8_t pdu[LATER_MAX][8];
    int n;
    int quit;
} later = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, {0}, {{0}}, 0, 0};

static int cb_raw(const modbus_request_info_t *ri, const uint8_t *pdu, int len, uint8_t *rsp, int max, void *ud)
{
    (void) ud;
    (void) rsp;
    (void) max;
    pthread_mutex_lock(&later.lock);
    if (later.n == LATER_MAX) {
        pthread_mutex_unlock(&later.lock);
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
    }
    later.id[later.n] = ri->request_id;
    memcpy(later.pdu[later.n], pdu, (size_t) (len < 8 ? len : 8));
    later.n++;
    pthread_cond_signal(&later.cond);
    pthread_mutex_unlock(&later.lock);
    return MODBUS_REPLY_LATER;
}

/* The typed answers: a read's values, a write done (rc 0: the library builds the
 * echo), an exception by its code; raw PDUs for the rest. */
static void answer_one(int id, const uint8_t *q)
{
    int addr = (q[1] << 8) | q[2], nb = (q[3] << 8) | q[4];
    if (q[0] == MODBUS_FC_READ_HOLDING_REGISTERS && addr == 999) {
        modbus_server_answer(server, id, NULL, MODBUS_REPLY_NONE);
    } else if ((q[0] == MODBUS_FC_READ_HOLDING_REGISTERS || q[0] == MODBUS_FC_READ_INPUT_REGISTERS) && nb >= 1 &&
               nb <= 125 && addr + nb <= NB) {
        const uint16_t *t =
            q[0] == MODBUS_FC_READ_INPUT_REGISTERS ? maps[0]->tab_input_registers : maps[0]->tab_registers;
        if (modbus_server_answer_registers(server, id, t + addr, nb) != 0) {
            fprintf(stderr, "modbus_server_answer_registers: %s\n", modbus_strerror(errno));
        }
    } else if (q[0] == MODBUS_FC_WRITE_SINGLE_REGISTER && addr < NB) {
        maps[0]->tab_registers[addr] = (uint16_t) nb;
        if (modbus_server_answer(server, id, NULL, 0) != 0) {
            fprintf(stderr, "modbus_server_answer (write done): %s\n", modbus_strerror(errno));
        }
    } else {
        modbus_server_answer_exception(server, id, MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    }
}

static void *later_thread(void *arg)
{
    (void) arg;
    pthread_mutex_lock(&later.lock);
    while (!later.quit) {
        struct timespec until;
        if (later.n == 0) {
            pthread_cond_wait(&later.cond, &later.lock);
            continue;
        }
        /* A burst gathers for up to 50 ms, then is answered last first. */
        clock_gettime(CLOCK_REALTIME, &until);
        until.tv_nsec += 50000000;
        if (until.tv_nsec >= 1000000000) {
            until.tv_sec++;
            until.tv_nsec -= 1000000000;
        }
        /* (the requests that come meanwhile signal: the wait goes on to its end) */
        while (!later.quit && pthread_cond_timedwait(&later.cond, &later.lock, &until) != ETIMEDOUT) {
        }
        while (later.n > 0) {
            later.n--;
            answer_one(later.id[later.n], later.pdu[later.n]);
        }
    }
    pthread_mutex_unlock(&later.lock);
    return NULL;
}

static void fill(modbus_mapping_t *m, int k)
{
    int i;
    for (i = 0; i < NB; i++) {
        m->tab_registers[i] = (uint16_t) (1000 * k + i);
        m->tab_input_registers[i] = (uint16_t) (1000 * k + i);
        m->tab_bits[i] = i % 3 == 0;
        m->tab_input_bits[i] = i % 3 == 0;
    }
}

int main(int argc, char **argv)
{
    modbus_server_callbacks_t cb;
    modbus_t *ctx;
    const char *mode;
    int callbacks = 0, idle_ms = -1, max = 1000, use_poll = 0, status = -1, bench = 0, port = 0, deferred = 0, i,
        next;
    pthread_t answerer;
    long total = 0;
    struct sigaction sa;

    if (argc < 3) {
        fprintf(stderr, "usage: runner-server tcp|rtutcp|tls|rtu|udp ADDR [...]\n");
        return 2;
    }
    print_loaded_libmodbus();
    mode = argv[1];
    next = strcmp(mode, "tls") == 0 ? 6 : 3;
    if (argc < next) {
        fprintf(stderr, "tls needs <port> <cert> <key> <ca>\n");
        return 2;
    }
    for (i = next; i < argc; i++) {
        if (strcmp(argv[i], "--callbacks") == 0) {
            callbacks = 1;
        } else if (strcmp(argv[i], "--idle") == 0 && i + 1 < argc) {
            idle_ms = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--max") == 0 && i + 1 < argc) {
            max = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--nofile") == 0 && i + 1 < argc) {
            /* Up to the hard limit, raised first where the process may. */
            struct rlimit rl;
            rlim_t want = (rlim_t) atol(argv[++i]);
            getrlimit(RLIMIT_NOFILE, &rl);
            if (rl.rlim_max < want) {
                struct rlimit raised = {want, want};
                if (setrlimit(RLIMIT_NOFILE, &raised) == 0) {
                    rl = raised;
                }
            }
            rl.rlim_cur = rl.rlim_max < want ? rl.rlim_max : want;
            if (setrlimit(RLIMIT_NOFILE, &rl) != 0) {
                perror("setrlimit");
                return 1;
            }
        } else if (strcmp(argv[i], "--status") == 0 && i + 1 < argc) {
            status = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--later") == 0) {
            deferred = 1;
        } else if (strcmp(argv[i], "--bench") == 0) {
            bench = 1;
        } else if (strcmp(argv[i], "--poll") == 0) {
            use_poll = 1;
        } else {
            fprintf(stderr, "unknown option %s\n", argv[i]);
            return 2;
        }
    }
    if (strcmp(mode, "tcp") == 0) {
        ctx = modbus_new_tcp("127.0.0.1", atoi(argv[2]));
    } else if (strcmp(mode, "rtutcp") == 0) {
        ctx = modbus_new_rtu_tcp("127.0.0.1", atoi(argv[2]));
        if (ctx != NULL) {
            modbus_set_slave(ctx, 1);
        }
    } else if (strcmp(mode, "tls") == 0) {
        ctx = modbus_new_tcp_tls("127.0.0.1", atoi(argv[2]));
        if (ctx != NULL && (modbus_set_tls_certificate(ctx, argv[3], argv[4]) != 0 ||
                            modbus_set_tls_ca(ctx, argv[5]) != 0)) {
            fprintf(stderr, "TLS settings: %s\n", modbus_strerror(errno));
            return 1;
        }
    } else if (strcmp(mode, "udp") == 0) {
        ctx = modbus_new_udp("127.0.0.1", atoi(argv[2]));
    } else if (strcmp(mode, "rtu") == 0) {
        ctx = modbus_new_rtu(argv[2], 115200, 'N', 8, 1);
        if (ctx != NULL) {
            modbus_set_slave(ctx, 1);
        }
    } else {
        fprintf(stderr, "unknown mode %s\n", mode);
        return 2;
    }
    if (ctx == NULL) {
        fprintf(stderr, "context: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (getenv("RUNNER_DEBUG") != NULL) {
        modbus_set_debug(ctx, TRUE);
    }
    if (status >= 0 && modbus_set_exception_status(ctx, status) != 0) {
        fprintf(stderr, "modbus_set_exception_status: %s\n", modbus_strerror(errno));
        return 1;
    }
    for (i = 0; i <= UNITS; i++) {
        maps[i] = modbus_mapping_new(NB, NB, NB, NB);
        fill(maps[i], i);
    }
    if (bench) {
        for (i = 0; i < NB; i++) {
            maps[0]->tab_registers[i] = (uint16_t) (3 * i);
        }
    }
    if (strcmp(mode, "tcp") == 0 && atoi(argv[2]) == 0) {
        /* An ephemeral port: listen here, and give the socket to the server. */
        struct sockaddr_in a;
        socklen_t len = sizeof a;
        int s = modbus_tcp_listen(ctx, max);
        if (s < 0 || getsockname(s, (struct sockaddr *) &a, &len) != 0) {
            fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
            return 1;
        }
        port = ntohs(a.sin_port);
        modbus_set_socket(ctx, s);
    }
    server = modbus_server_new(ctx, max);
    if (server == NULL) {
        fprintf(stderr, "modbus_server_new: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (callbacks) {
        memset(&cb, 0, sizeof cb);
        cb.struct_size = sizeof cb;
        cb.accept_unit = cb_accept;
        cb.read_bits = cb_read_bits;
        cb.read_registers = cb_read_registers;
        cb.write_bits = cb_write_bits;
        cb.write_registers = cb_write_registers;
        modbus_server_set_callbacks(server, &cb, NULL);
    } else if (deferred) {
        memset(&cb, 0, sizeof cb);
        cb.struct_size = sizeof cb;
        cb.raw = cb_raw;
        modbus_server_set_callbacks(server, &cb, NULL);
        pthread_create(&answerer, NULL, later_thread, NULL);
    } else {
        modbus_server_set_mapping(server, maps[0]);
    }
    if (idle_ms >= 0 && modbus_server_set_idle_timeout(server, (uint32_t) idle_ms / 1000,
                                                       (uint32_t) (idle_ms % 1000) * 1000) != 0) {
        fprintf(stderr, "idle timeout: %s\n", modbus_strerror(errno));
        return 1;
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    if (port > 0) {
        printf("READY %d\n", port);
    } else {
        printf("READY\n");
    }
    fflush(stdout);
    if (use_poll) {
        struct pollfd pfd = {modbus_server_get_fd(server), POLLIN, 0};
        for (;;) {
            int rc;
            if (poll(&pfd, 1, -1) < 0 && errno != EINTR) {
                perror("poll");
                return 1;
            }
            rc = modbus_server_run(server, 0);
            if (rc < 0) {
                fprintf(stderr, "modbus_server_run: %s\n", modbus_strerror(errno));
                return 1;
            }
            total += rc;
            if (signalled) {
                break;
            }
        }
    } else {
        int rc = modbus_server_run(server, -1);
        if (rc < 0) {
            fprintf(stderr, "modbus_server_run: %s\n", modbus_strerror(errno));
            return 1;
        }
        total = rc;
    }
    if (deferred) {
        pthread_mutex_lock(&later.lock);
        later.quit = 1;
        pthread_cond_signal(&later.cond);
        pthread_mutex_unlock(&later.lock);
        pthread_join(answerer, NULL);
    }
    printf("stopped%s, %ld requests answered\n", signalled ? " by a signal" : "", total);
    modbus_server_free(server);
    for (i = 0; i <= UNITS; i++) {
        modbus_mapping_free(maps[i]);
    }
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
