/*
 * rsmodbus-gateway: Modbus/TCP masters in front of a serial Modbus line, built on
 * rsmodbus' own pieces: the server that runs itself (modbus_server_new, its `raw`
 * callback and MODBUS_REPLY_LATER / modbus_server_answer) in front, the event-driven
 * client (modbus_send_raw_request_async, modbus_process) on the line. It takes
 * mbusd's command line and configuration file, with mbusd's meanings and defaults,
 * and answers as mbusd does: exception 0x0B when the device does not answer, 0x04
 * when its answers keep failing the CRC after the retries.
 *
 * Past mbusd: a Modbus/TCP Security front (mutual TLS, port 802 by default when
 * tls_cert is set) whose policy maps the role in each master's certificate to the
 * units and the access (read, or read and write) it may have: refused, exception
 * 0x01; fronts for RTU over TCP and Modbus/UDP; a Modbus/TCP or RTU-over-TCP
 * device in place of the serial line. Each master's requests wait in a queue of
 * their own and the line
 * serves the masters in turn, so one master in a tight loop cannot starve the others
 * (a full queue: exception 0x06); Modbus ASCII lines (-m 7E1a / mode = 8N1 ascii:
 * a trailing 'a', or "ascii"); every function code passes through, the extension
 * codes included.
 *
 * The program is one thread and one poll() over the server's epoll descriptor and
 * the line.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#define VERSION "0.1.0"
#define QUEUE_MAX 16 /* requests one master may have waiting */

/* ---------------------------------------------------------------- configuration */

struct config {
    int loglevel;
    char logfile[256];
    char device[256];
    int speed;
    char mode[16];
    int rs485;
    int trx; /* 0 none (addc), 1 rts active transmit, 2 rts active receive, 3/4 sysfs */
    char trx_sysfile[256];
    char address[64];
    int port;
    int maxconn;
    int timeout; /* idle connection timeout, s */
    int retries;
    int pause; /* ms between requests */
    int wait;  /* ms for an answer */
    int replyonbroadcast;
    int foreground;
    /* Modbus/TCP Security front (extended keys: tls_*). */
    char tls_address[64];
    int tls_port;
    char tls_cert[256], tls_key[256], tls_ca[256];
    /* More fronts (0: none) and another kind of line (extended keys). */
    int rtutcp_port, udp_port;
    char backend[16];      /* "serial" (the device), "tcp" or "rtutcp" */
    char back_host[256];
    char back_port[16];
};

/* tls_role.<Role> = r|rw FIRST-LAST: what masters of that role may do. */
#define ROLES_MAX 16
static struct role {
    char name[64];
    int write;
    int first, last;
} roles[ROLES_MAX];
static int nroles;

static struct config cfg = {
    2, "/var/log/rsmodbus-gateway.log", "/dev/ttyS0", 19200, "8N1", 0, 0, "", "0.0.0.0", 502, 32, 60, 3, 100, 500, 0, 0,
    "0.0.0.0", 802, "", "", "", 0, 0, "serial", "", "",
};

static FILE *logf;

static void logw(int level, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void logw(int level, const char *fmt, ...)
{
    va_list ap;
    struct timespec ts;
    struct tm tm;
    char stamp[32];
    if (level > cfg.loglevel) {
        return;
    }
    clock_gettime(CLOCK_REALTIME, &ts);
    localtime_r(&ts.tv_sec, &tm);
    strftime(stamp, sizeof stamp, "%d %b %Y %H:%M:%S", &tm);
    va_start(ap, fmt);
    if (logf != NULL) {
        fprintf(logf, "%s %s", stamp, level == 0 ? "ERROR: " : "");
        vfprintf(logf, fmt, ap);
        fputc('\n', logf);
        fflush(logf);
    }
    va_end(ap);
}

static void usage(FILE *out)
{
    fprintf(out,
            "rsmodbus-gateway " VERSION ": Modbus/TCP to Modbus RTU/ASCII gateway (rsmodbus; mbusd's options)\n\n"
            "Usage: rsmodbus-gateway [-h] [-d] [-L logfile] [-v level] [-c cfgfile]\n"
            "                        [-p device] [-s speed] [-m mode] [-S]\n"
            "                        [-t] [-r] [-y sysfsfile] [-Y sysfsfile]\n"
            "                        [-A address] [-P port] [-C maxconn] [-N retries]\n"
            "                        [-R pause] [-W wait] [-T timeout] [-b]\n\n"
            "Options:\n"
            "  -h         : this help\n"
            "  -d         : don't fork (stay in the foreground)\n"
            "  -L logfile : log file (default /var/log/rsmodbus-gateway.log; '-': standard output)\n"
            "  -v level   : log level (0-9, default 2; 0: errors only)\n"
            "  -c cfgfile : read the configuration from cfgfile (key = value lines)\n"
            "  -p device  : serial device (default /dev/ttyS0)\n"
            "  -s speed   : serial speed (default 19200)\n"
            "  -m mode    : serial mode (default 8N1; a trailing 'a', e.g. 7E1a: Modbus ASCII)\n"
            "  -S         : Linux RS-485 mode on the serial device\n"
            "  -t         : RS-485 direction by RTS, active on transmit\n"
            "  -r         : RS-485 direction by RTS, active on receive\n"
            "  -y file    : RS-485 direction by writing 1 (transmit) / 0 to a sysfs file\n"
            "  -Y file    : RS-485 direction by writing 0 (transmit) / 1 to a sysfs file\n"
            "  -A address : TCP address to bind (default 0.0.0.0; IPv6 accepted)\n"
            "  -P port    : TCP port (default 502)\n"
            "  -C maxconn : most simultaneous TCP connections (1-128, default 32)\n"
            "  -N retries : retries of a request (0-15, default 3; 0: none)\n"
            "  -R pause   : pause between requests in milliseconds (1-10000, default 100)\n"
            "  -W wait    : answer wait in milliseconds (1-10000, default 500)\n"
            "  -T timeout : idle connection timeout in seconds (0-1000, default 60; 0: none)\n"
            "  -b         : reply to broadcasts (the request echoed)\n\n"
            "Exceptions: 0x0B when the device does not answer, 0x04 when its answers keep failing\n"
            "the CRC, 0x06 when a master has %d requests waiting.\n",
            QUEUE_MAX);
}

static int in_range(const char *what, const char *text, int lo, int hi, int *out)
{
    char *end;
    long v = strtol(text, &end, 10);
    if (*text == '\0' || *end != '\0' || v < lo || v > hi) {
        fprintf(stderr, "rsmodbus-gateway: %s must be %d to %d, not '%s'\n", what, lo, hi, text);
        return -1;
    }
    *out = (int) v;
    return 0;
}

static void copy(char *dst, size_t n, const char *src)
{
    snprintf(dst, n, "%s", src);
}

static int truthy(const char *v)
{
    return strcasecmp(v, "yes") == 0 || strcasecmp(v, "true") == 0 || strcmp(v, "1") == 0 ||
           strcasecmp(v, "on") == 0;
}

/* Reads mbusd's configuration file: `key = value` lines, '#' comments. */
static int read_config(const char *path)
{
    FILE *f = fopen(path, "r");
    char line[512];
    int n = 0;
    if (f == NULL) {
        fprintf(stderr, "rsmodbus-gateway: cannot open %s: %s\n", path, strerror(errno));
        return -1;
    }
    while (fgets(line, sizeof line, f) != NULL) {
        char *k = line, *v, *e;
        n++;
        if ((e = strchr(k, '#')) != NULL) {
            *e = '\0';
        }
        while (*k == ' ' || *k == '\t') {
            k++;
        }
        if (*k == '\0' || *k == '\n') {
            continue;
        }
        v = strchr(k, '=');
        if (v == NULL) {
            fprintf(stderr, "rsmodbus-gateway: %s:%d: no '='\n", path, n);
            fclose(f);
            return -1;
        }
        *v++ = '\0';
        for (e = v + strlen(v); e > v && (e[-1] == '\n' || e[-1] == ' ' || e[-1] == '\t' || e[-1] == '\r'); e--) {
            e[-1] = '\0';
        }
        while (*v == ' ' || *v == '\t') {
            v++;
        }
        for (e = k + strlen(k); e > k && (e[-1] == ' ' || e[-1] == '\t'); e--) {
            e[-1] = '\0';
        }
        int rc = 0;
        if (strcmp(k, "loglevel") == 0) {
            rc = in_range("loglevel", v, 0, 9, &cfg.loglevel);
        } else if (strcmp(k, "logfile") == 0) {
            copy(cfg.logfile, sizeof cfg.logfile, v);
        } else if (strcmp(k, "device") == 0) {
            copy(cfg.device, sizeof cfg.device, v);
        } else if (strcmp(k, "speed") == 0) {
            rc = in_range("speed", v, 1, 10000000, &cfg.speed);
        } else if (strcmp(k, "mode") == 0) {
            copy(cfg.mode, sizeof cfg.mode, v);
        } else if (strcmp(k, "enable_rs485") == 0) {
            cfg.rs485 = truthy(v);
        } else if (strcmp(k, "trx_control") == 0) {
            if (strcmp(v, "addc") == 0) {
                cfg.trx = 0;
            } else if (strcmp(v, "rts") == 0 || strcmp(v, "rts_1") == 0) {
                cfg.trx = 1;
            } else if (strcmp(v, "rts_0") == 0) {
                cfg.trx = 2;
            } else if (strcmp(v, "sysfs_1") == 0) {
                cfg.trx = 3;
            } else if (strcmp(v, "sysfs_0") == 0) {
                cfg.trx = 4;
            } else {
                fprintf(stderr, "rsmodbus-gateway: %s:%d: unknown trx_control '%s'\n", path, n, v);
                rc = -1;
            }
        } else if (strcmp(k, "trx_sysfile") == 0) {
            copy(cfg.trx_sysfile, sizeof cfg.trx_sysfile, v);
        } else if (strcmp(k, "address") == 0) {
            copy(cfg.address, sizeof cfg.address, v);
        } else if (strcmp(k, "port") == 0) {
            rc = in_range("port", v, 1, 65535, &cfg.port);
        } else if (strcmp(k, "maxconn") == 0) {
            rc = in_range("maxconn", v, 1, 128, &cfg.maxconn);
        } else if (strcmp(k, "timeout") == 0) {
            rc = in_range("timeout", v, 0, 1000, &cfg.timeout);
        } else if (strcmp(k, "retries") == 0) {
            rc = in_range("retries", v, 0, 15, &cfg.retries);
        } else if (strcmp(k, "pause") == 0) {
            rc = in_range("pause", v, 1, 10000, &cfg.pause);
        } else if (strcmp(k, "wait") == 0) {
            rc = in_range("wait", v, 1, 10000, &cfg.wait);
        } else if (strcmp(k, "replyonbroadcast") == 0) {
            cfg.replyonbroadcast = truthy(v);
        } else if (strcmp(k, "rtutcp_port") == 0) {
            rc = in_range("rtutcp_port", v, 0, 65535, &cfg.rtutcp_port);
        } else if (strcmp(k, "udp_port") == 0) {
            rc = in_range("udp_port", v, 0, 65535, &cfg.udp_port);
        } else if (strcmp(k, "backend") == 0) {
            char kind[16] = "", host[256] = "", bport[16] = "";
            if (sscanf(v, "%15s %255s %15s", kind, host, bport) < 1 ||
                (strcmp(kind, "serial") != 0 &&
                 ((strcmp(kind, "tcp") != 0 && strcmp(kind, "rtutcp") != 0) || host[0] == '\0' || bport[0] == '\0'))) {
                fprintf(stderr, "rsmodbus-gateway: %s:%d: backend must be 'serial', 'tcp HOST PORT' or 'rtutcp HOST PORT'\n",
                        path, n);
                rc = -1;
            } else {
                copy(cfg.backend, sizeof cfg.backend, kind);
                copy(cfg.back_host, sizeof cfg.back_host, host);
                copy(cfg.back_port, sizeof cfg.back_port, bport);
            }
        } else if (strcmp(k, "tls_address") == 0) {
            copy(cfg.tls_address, sizeof cfg.tls_address, v);
        } else if (strcmp(k, "tls_port") == 0) {
            rc = in_range("tls_port", v, 1, 65535, &cfg.tls_port);
        } else if (strcmp(k, "tls_cert") == 0) {
            copy(cfg.tls_cert, sizeof cfg.tls_cert, v);
        } else if (strcmp(k, "tls_key") == 0) {
            copy(cfg.tls_key, sizeof cfg.tls_key, v);
        } else if (strcmp(k, "tls_ca") == 0) {
            copy(cfg.tls_ca, sizeof cfg.tls_ca, v);
        } else if (strncmp(k, "tls_role.", 9) == 0) {
            char access[8];
            struct role *r = &roles[nroles];
            if (nroles == ROLES_MAX || sscanf(v, "%7s %d-%d", access, &r->first, &r->last) != 3 ||
                (strcmp(access, "r") != 0 && strcmp(access, "rw") != 0) || r->first < 0 || r->last > 255 ||
                r->first > r->last) {
                fprintf(stderr, "rsmodbus-gateway: %s:%d: %s must be 'r FIRST-LAST' or 'rw FIRST-LAST'\n", path, n, k);
                rc = -1;
            } else {
                copy(r->name, sizeof r->name, k + 9);
                r->write = strcmp(access, "rw") == 0;
                nroles++;
            }
        } else {
            fprintf(stderr, "rsmodbus-gateway: %s:%d: unknown key '%s'\n", path, n, k);
            rc = -1;
        }
        if (rc != 0) {
            fclose(f);
            return -1;
        }
    }
    fclose(f);
    return 0;
}

/* ---------------------------------------------------------------- masters and the line */

struct request {
    modbus_server_t *server; /* the front it came through */
    uint32_t id;   /* that server's, for modbus_server_answer */
    int len;       /* of raw: unit + PDU */
    uint8_t raw[MODBUS_MAX_PDU_LENGTH + 1];
    int tries;     /* sends so far */
};

struct master {
    int socket;
    struct request q[QUEUE_MAX];
    int head, n;
};

/* A front: the masters' side, one server that runs itself per kind. */
struct front {
    const char *what;
    modbus_t *ctx;
    modbus_server_t *server;
};
#define FRONTS_MAX 4

static struct {
    struct front fronts[FRONTS_MAX];
    int nfronts;
    int header;   /* the line's answer header: 1 (serial, RTU over TCP) or 7 (TCP) */
    int checksum; /* and its checksum: 2 (RTU), 1 (ASCII), 0 (TCP) */
    modbus_t *line;
    struct master *masters;
    int nmasters, cap;
    int turn;                 /* the master served last */
    int busy;                 /* a request is on the line */
    struct request current;   /* it */
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    double quiet_until;       /* the pause after a transaction */
    int ascii;
    long served, timeouts, crc_errors;
} G;

static volatile sig_atomic_t stopping;

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

static struct master *master_of(int socket)
{
    int i;
    for (i = 0; i < G.nmasters; i++) {
        if (G.masters[i].socket == socket) {
            return &G.masters[i];
        }
    }
    /* A slot of a master with nothing queued is reused (its socket may be closed),
     * but not that of the request on the line (a retry goes back there). */
    for (i = 0; i < G.nmasters; i++) {
        if (G.masters[i].n == 0 && !(G.busy && i == G.turn)) {
            G.masters[i].socket = socket;
            G.masters[i].head = 0;
            return &G.masters[i];
        }
    }
    if (G.nmasters == G.cap) {
        int cap = G.cap ? 2 * G.cap : 16;
        struct master *m = realloc(G.masters, (size_t) cap * sizeof *m);
        if (m == NULL) {
            return NULL;
        }
        G.masters = m;
        G.cap = cap;
    }
    memset(&G.masters[G.nmasters], 0, sizeof G.masters[0]);
    G.masters[G.nmasters].socket = socket;
    return &G.masters[G.nmasters++];
}

/* The server's raw callback: every request of every master, queued for the line. */
static int on_request(void *user_data, const modbus_request_info_t *ri, const uint8_t *pdu, int pdu_length,
                      uint8_t *rsp_pdu, int rsp_max)
{
    /* (A socket number names one master across both fronts: one process.) */
    struct master *m = master_of(ri->socket);
    struct request *r;
    (void) user_data;
    (void) rsp_pdu;
    (void) rsp_max;
    if (m == NULL || m->n == QUEUE_MAX) {
        logw(1, "master on socket %d: queue full, request 0x%02X refused (busy)", ri->socket, ri->function);
        return -MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY;
    }
    r = &m->q[(m->head + m->n) % QUEUE_MAX];
    r->id = ri->request_id;
    r->server = ((struct front *) user_data)->server;
    r->raw[0] = (uint8_t) ri->unit_id;
    memcpy(r->raw + 1, pdu, (size_t) pdu_length);
    r->len = pdu_length + 1;
    r->tries = 0;
    m->n++;
    logw(5, "master on socket %d: request 0x%02X for unit %d queued (%d waiting)", ri->socket, ri->function,
         ri->unit_id, m->n);
    return MODBUS_REPLY_LATER;
}

static void on_answer(modbus_t *ctx, int id, int rc, int error, void *user_data);

static int every_unit(void *user_data, int unit)
{
    (void) user_data;
    (void) unit;
    return 1;
}

/* Puts the next request on the line: the next master with one waiting, in turn. */
static void dispatch(void)
{
    int k;
    if (G.busy || now_ms() < G.quiet_until) {
        return;
    }
    for (k = 1; k <= G.nmasters; k++) {
        struct master *m = &G.masters[(G.turn + k) % G.nmasters];
        if (m->n == 0) {
            continue;
        }
        G.turn = (G.turn + k) % G.nmasters;
        G.current = m->q[m->head];
        m->head = (m->head + 1) % QUEUE_MAX;
        m->n--;
        break;
    }
    if (k > G.nmasters) {
        return;
    }
    G.current.tries++;
    G.busy = 1;
    if (modbus_send_raw_request_async(G.line, G.current.raw, G.current.len, G.rsp, on_answer, NULL) < 0) {
        logw(0, "line: cannot send (%s)", modbus_strerror(errno));
        G.busy = 0;
        modbus_server_answer(G.current.server, G.current.id, NULL, -MODBUS_EXCEPTION_GATEWAY_TARGET);
    }
}

/* The line's answer (or its failure) to the current request. */
static void on_answer(modbus_t *ctx, int id, int rc, int error, void *user_data)
{
    struct request *r = &G.current;
    int h = G.header, crc = G.checksum;
    (void) ctx;
    (void) id;
    (void) user_data;
    G.busy = 0;
    G.quiet_until = now_ms() + cfg.pause;
    if (r->raw[0] == 0) {
        /* A broadcast: out, no answer expected; the request echoed with -b. */
        modbus_server_answer(r->server, r->id, cfg.replyonbroadcast ? r->raw + 1 : NULL,
                             cfg.replyonbroadcast ? r->len - 1 : MODBUS_REPLY_NONE);
        return;
    }
    if (rc > h + crc) {
        G.served++;
        modbus_server_answer(r->server, r->id, G.rsp + h, rc - h - crc);
        return;
    }
    if (error == EMBBADCRC || error == EMBBADDATA) {
        G.crc_errors++;
    } else {
        G.timeouts++;
    }
    if (r->tries <= cfg.retries) {
        logw(3, "line: unit %d, request 0x%02X: %s, try %d of %d", r->raw[0], r->raw[1], modbus_strerror(error),
             r->tries + 1, cfg.retries + 1);
        /* Again, first in line (after the pause). */
        struct request again = *r;
        struct master *m = &G.masters[G.turn];
        if (m->n < QUEUE_MAX) {
            m->head = (m->head + QUEUE_MAX - 1) % QUEUE_MAX;
            m->q[m->head] = again;
            m->n++;
            G.turn = (G.turn + G.nmasters - 1) % G.nmasters;
            return;
        }
    }
    logw(1, "line: unit %d, request 0x%02X: %s after %d tries", r->raw[0], r->raw[1], modbus_strerror(error),
         r->tries);
    modbus_server_answer(r->server, r->id, NULL,
                         error == EMBBADCRC || error == EMBBADDATA ? -MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE
                                                                   : -MODBUS_EXCEPTION_GATEWAY_TARGET);
}

/* The Modbus/TCP Security policy: the master's role (in its certificate) must have
 * a tls_role line naming the unit, and "rw" for anything but a read. */
static int authorize(modbus_t *ctx, const char *role, int unit_id, int function, int address, int nb,
                     void *user_data)
{
    int i, read = function >= MODBUS_FC_READ_COILS && function <= MODBUS_FC_READ_INPUT_REGISTERS;
    (void) ctx;
    (void) address;
    (void) nb;
    (void) user_data;
    for (i = 0; role != NULL && i < nroles; i++) {
        if (strcmp(roles[i].name, role) == 0 && unit_id >= roles[i].first && unit_id <= roles[i].last &&
            (read || roles[i].write)) {
            return 1;
        }
    }
    logw(3, "TLS master with role %s refused: unit %d, function 0x%02X", role != NULL ? role : "(none)", unit_id,
         function);
    return 0;
}

static void on_signal(int sig)
{
    (void) sig;
    stopping = 1;
    int i;
    for (i = 0; i < G.nfronts; i++) {
        modbus_server_stop(G.fronts[i].server);
    }
}

/* "8N1", "7E1a": data bits, parity, stop bits, ASCII. */
static int parse_mode(const char *mode, int *data, char *parity, int *stop, int *ascii)
{
    size_t n = strlen(mode);
    *ascii = 0;
    if (n == 4 && (mode[3] == 'a' || mode[3] == 'A')) {
        *ascii = 1;
        n = 3;
    }
    if (n != 3 || mode[0] < '5' || mode[0] > '8' || strchr("NEOneo", mode[1]) == NULL || (mode[2] != '1' && mode[2] != '2')) {
        return -1;
    }
    *data = mode[0] - '0';
    *parity = (char) (mode[1] & ~0x20);
    *stop = mode[2] - '0';
    return 0;
}

int main(int argc, char **argv)
{
    int opt, data, stop;
    char parity;
    modbus_server_callbacks_t cb;
    char port[16];
    int i;

    while ((opt = getopt(argc, argv, "hdL:v:c:p:s:m:Stry:Y:A:P:C:N:R:W:T:b")) != -1) {
        switch (opt) {
        case 'h':
            usage(stdout);
            return 0;
        case 'd':
            cfg.foreground = 1;
            break;
        case 'L':
            copy(cfg.logfile, sizeof cfg.logfile, optarg);
            break;
        case 'v':
            if (in_range("-v", optarg, 0, 9, &cfg.loglevel) != 0) {
                return 1;
            }
            break;
        case 'c':
            if (read_config(optarg) != 0) {
                return 1;
            }
            break;
        case 'p':
            copy(cfg.device, sizeof cfg.device, optarg);
            break;
        case 's':
            if (in_range("-s", optarg, 1, 10000000, &cfg.speed) != 0) {
                return 1;
            }
            break;
        case 'm':
            copy(cfg.mode, sizeof cfg.mode, optarg);
            break;
        case 'S':
            cfg.rs485 = 1;
            break;
        case 't':
            cfg.trx = 1;
            break;
        case 'r':
            cfg.trx = 2;
            break;
        case 'y':
            cfg.trx = 3;
            copy(cfg.trx_sysfile, sizeof cfg.trx_sysfile, optarg);
            break;
        case 'Y':
            cfg.trx = 4;
            copy(cfg.trx_sysfile, sizeof cfg.trx_sysfile, optarg);
            break;
        case 'A':
            copy(cfg.address, sizeof cfg.address, optarg);
            break;
        case 'P':
            if (in_range("-P", optarg, 1, 65535, &cfg.port) != 0) {
                return 1;
            }
            break;
        case 'C':
            if (in_range("-C", optarg, 1, 128, &cfg.maxconn) != 0) {
                return 1;
            }
            break;
        case 'N':
            if (in_range("-N", optarg, 0, 15, &cfg.retries) != 0) {
                return 1;
            }
            break;
        case 'R':
            if (in_range("-R", optarg, 1, 10000, &cfg.pause) != 0) {
                return 1;
            }
            break;
        case 'W':
            if (in_range("-W", optarg, 1, 10000, &cfg.wait) != 0) {
                return 1;
            }
            break;
        case 'T':
            if (in_range("-T", optarg, 0, 1000, &cfg.timeout) != 0) {
                return 1;
            }
            break;
        case 'b':
            cfg.replyonbroadcast = 1;
            break;
        default:
            usage(stderr);
            return 1;
        }
    }
    if (parse_mode(cfg.mode, &data, &parity, &stop, &G.ascii) != 0) {
        fprintf(stderr, "rsmodbus-gateway: serial mode '%s' is not like 8N1 (or 7E1a for ASCII)\n", cfg.mode);
        return 1;
    }
    if (strcmp(cfg.logfile, "-") == 0) {
        logf = stdout;
    } else {
        char path[300];
        if (strchr(cfg.logfile, '/') == NULL) {
            snprintf(path, sizeof path, "/var/log/%s", cfg.logfile);
        } else {
            copy(path, sizeof path, cfg.logfile);
        }
        logf = fopen(path, "a");
        if (logf == NULL) {
            fprintf(stderr, "rsmodbus-gateway: cannot open the log file %s: %s\n", path, strerror(errno));
            return 1;
        }
    }

    /* The line: a serial one, or a device on the network (RTU frames over TCP, or
     * Modbus/TCP: one connection that every master's requests share). */
    G.header = 1;
    G.checksum = G.ascii ? 1 : 2;
    if (strcmp(cfg.backend, "tcp") == 0) {
        G.line = modbus_new_tcp_pi(cfg.back_host, cfg.back_port);
        G.header = 7;
        G.checksum = 0;
    } else if (strcmp(cfg.backend, "rtutcp") == 0) {
        G.line = modbus_new_rtu_tcp_pi(cfg.back_host, cfg.back_port);
        G.checksum = 2;
    } else {
        G.line = G.ascii ? modbus_new_ascii(cfg.device, cfg.speed, parity, data, stop)
                         : modbus_new_rtu(cfg.device, cfg.speed, parity, data, stop);
    }
    if (G.line == NULL) {
        logw(0, "line %s: %s", cfg.device, modbus_strerror(errno));
        return 1;
    }
    modbus_set_response_timeout(G.line, (uint32_t) cfg.wait / 1000, (uint32_t) (cfg.wait % 1000) * 1000);
    /* Levels 8 and 9 trace the line's frames (libmodbus' debug output). */
    modbus_set_debug(G.line, cfg.loglevel >= 8);
    if (strcmp(cfg.backend, "serial") != 0) {
        /* A device on the network reconnects by itself when it is lost. */
        modbus_set_error_recovery(G.line, MODBUS_ERROR_RECOVERY_LINK);
        if (modbus_connect(G.line) != 0) {
            logw(1, "line %s %s:%s: %s (the first request connects again)", cfg.backend, cfg.back_host, cfg.back_port,
                 modbus_strerror(errno));
        }
    } else if (modbus_connect(G.line) != 0) {
        logw(0, "line %s: %s", cfg.device, modbus_strerror(errno));
        return 1;
    }
    if (cfg.rs485 && modbus_rtu_set_serial_mode(G.line, MODBUS_RTU_RS485) != 0) {
        logw(0, "line %s: RS-485 mode: %s", cfg.device, modbus_strerror(errno));
        return 1;
    }
    if (cfg.trx == 1 || cfg.trx == 2) {
        modbus_rtu_set_rts(G.line, cfg.trx == 1 ? MODBUS_RTU_RTS_UP : MODBUS_RTU_RTS_DOWN);
    } else if (cfg.trx >= 3) {
        logw(0, "RS-485 direction through a sysfs file (-y, -Y) is not supported; use -S or -t/-r");
        return 1;
    }

    /* The fronts: Modbus/TCP; RTU frames over TCP and Modbus/UDP when asked; and
     * Modbus/TCP Security with its policy. */
    {
        const char *any = strcmp(cfg.address, "0.0.0.0") == 0 ? NULL : cfg.address;
        snprintf(port, sizeof port, "%d", cfg.port);
        G.fronts[G.nfronts++] = (struct front) {"Modbus/TCP", modbus_new_tcp_pi(any, port), NULL};
        if (cfg.rtutcp_port > 0) {
            snprintf(port, sizeof port, "%d", cfg.rtutcp_port);
            G.fronts[G.nfronts++] = (struct front) {"RTU over TCP", modbus_new_rtu_tcp_pi(any, port), NULL};
        }
        if (cfg.udp_port > 0) {
            snprintf(port, sizeof port, "%d", cfg.udp_port);
            G.fronts[G.nfronts++] = (struct front) {"Modbus/UDP", modbus_new_udp_pi(any, port), NULL};
        }
        if (cfg.tls_cert[0] != '\0') {
            modbus_t *t;
            snprintf(port, sizeof port, "%d", cfg.tls_port);
            t = modbus_new_tcp_tls_pi(strcmp(cfg.tls_address, "0.0.0.0") == 0 ? NULL : cfg.tls_address, port);
            if (t != NULL && (modbus_set_tls_certificate(t, cfg.tls_cert, cfg.tls_key) != 0 ||
                              modbus_set_tls_ca(t, cfg.tls_ca) != 0 ||
                              modbus_set_tls_authorization(t, authorize, NULL) != 0)) {
                logw(0, "Modbus/TCP Security front: %s", modbus_strerror(errno));
                return 1;
            }
            G.fronts[G.nfronts++] = (struct front) {"Modbus/TCP Security", t, NULL};
        }
    }
    memset(&cb, 0, sizeof cb);
    cb.struct_size = sizeof cb;
    cb.raw = on_request;
    /* Every unit is the line's (an RTU-framed front takes them all). */
    cb.accept_unit = every_unit;
    for (i = 0; i < G.nfronts; i++) {
        struct front *f = &G.fronts[i];
        if (f->ctx == NULL || (f->server = modbus_server_new(f->ctx, cfg.maxconn)) == NULL) {
            logw(0, "%s front: %s", f->what, modbus_strerror(errno));
            return 1;
        }
        modbus_server_set_callbacks(f->server, &cb, f);
        modbus_server_set_idle_timeout(f->server, (uint32_t) cfg.timeout, 0);
        logw(2, "%s front ready", f->what);
    }

    if (!cfg.foreground && daemon(0, logf == stdout) != 0) {
        logw(0, "daemon: %s", strerror(errno));
        return 1;
    }
    signal(SIGPIPE, SIG_IGN);
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    logw(2, "rsmodbus-gateway " VERSION " started: %s:%d -> %s %d %s%s", cfg.address, cfg.port, cfg.device,
         cfg.speed, cfg.mode, G.ascii ? " (ASCII)" : "");

    while (!stopping) {
        struct pollfd pfd[1 + FRONTS_MAX];
        int line_timeout, timeout = -1, failed = 0;
        for (i = 0; i < G.nfronts; i++) {
            pfd[1 + i].fd = modbus_server_get_fd(G.fronts[i].server);
            pfd[1 + i].events = POLLIN;
        }
        modbus_get_pollfd(G.line, &pfd[0], &line_timeout);
        timeout = line_timeout;
        if (!G.busy && G.quiet_until > now_ms()) {
            int pause = (int) (G.quiet_until - now_ms()) + 1;
            timeout = timeout < 0 || pause < timeout ? pause : timeout;
        }
        logw(9, "loop: line fd %d events 0x%x, timeout %d ms, busy %d", pfd[0].fd, pfd[0].events, timeout, G.busy);
        if (poll(pfd, (nfds_t) (1 + G.nfronts), timeout) < 0 && errno != EINTR) {
            logw(0, "poll: %s", strerror(errno));
            break;
        }
        for (i = 0; i < G.nfronts && !failed; i++) {
            if (modbus_server_run(G.fronts[i].server, 0) < 0) {
                logw(0, "%s front: %s", G.fronts[i].what, modbus_strerror(errno));
                failed = 1;
            }
        }
        if (failed) {
            break;
        }
        if (pfd[0].fd >= 0 || modbus_pending(G.line) > 0) {
            modbus_process(G.line, pfd[0].revents);
        }
        dispatch();
    }
    logw(2, "rsmodbus-gateway stopped: %ld answers, %ld timeouts, %ld bad answers", G.served, G.timeouts,
         G.crc_errors);
    for (i = 0; i < G.nfronts; i++) {
        modbus_server_free(G.fronts[i].server);
        modbus_free(G.fronts[i].ctx);
    }
    modbus_close(G.line);
    modbus_free(G.line);
    free(G.masters);
    return 0;
}
