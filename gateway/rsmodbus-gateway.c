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

/* ---------------------------------------------------------------- masters and lines */

struct request {
    modbus_server_t *server; /* the front it came through */
    int id;        /* that server's, for modbus_server_answer */
    int len;       /* of raw: unit (as sent on the line) + PDU */
    uint8_t raw[MODBUS_MAX_PDU_LENGTH + 1];
    int tries;     /* sends so far */
};

struct master {
    uint64_t conn; /* its connection (modbus_request_info_t's connection_id) */
    struct request q[QUEUE_MAX];
    int head, n;
    long requests, busy; /* requests taken, refused as busy (since its connection came) */
};

/* A line: a serial one, or a device on the network; its own masters' queues. */
struct line {
    char name[32];
    char kind[16]; /* serial, tcp, rtutcp */
    char device[256], mode[16], host[256], port[16];
    int speed;
    modbus_t *ctx;
    int header;   /* its answers' header (modbus_get_header_length) */
    int checksum; /* and checksum (modbus_get_checksum_length) */
    int ascii;
    struct master *masters;
    int nmasters, cap;
    int turn;               /* the master served last */
    int busy;               /* a request is on the line */
    struct request current; /* it */
    uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
    double quiet_until;     /* the pause after a transaction */
    double gap_ms;          /* a serial line's 3.5 characters at its speed (-R 0) */
    long requests, served, timeouts, crc_errors, exceptions;
};
#define LINES_MAX 8
static struct line lines[LINES_MAX] = {{.name = "default", .kind = "serial"}};
static int nlines = 1;

/* route = FIRST-LAST LINE [OFFSET]: units FIRST..LAST go to LINE as unit + OFFSET. */
#define ROUTES_MAX 32
static struct route {
    int first, last, line, offset;
} routes[ROUTES_MAX];
static int nroutes;

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
    char status_file[256]; /* counters, rewritten every second (extended key) */
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
    "0.0.0.0", 802, "", "", "", 0, 0, "serial", "", "", "",
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

/* The RTS hook of -y/-Y (trx_control = sysfs_1/sysfs_0): `on` is the level the
 * library wants (1 while sending for -y, 0 for -Y), written as the file's text. The
 * file is opened each time (mbusd does the same): "1" or "0", no newline. */
static void sysfs_direction(modbus_t *ctx, int on)
{
    int fd = open(cfg.trx_sysfile, O_WRONLY | O_CLOEXEC);
    (void) ctx;
    if (fd < 0 || write(fd, on ? "1" : "0", 1) != 1) {
        logw(1, "RS-485 direction file %s: %s", cfg.trx_sysfile, strerror(errno));
    }
    if (fd >= 0) {
        close(fd);
    }
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
            "  -C maxconn : most simultaneous connections (1-10000, default 32; mbusd: up to 128)\n"
            "  -N retries : retries of a request (0-15, default 3; 0: none)\n"
            "  -R pause   : pause between requests in milliseconds (0-10000, default 100;\n"
            "               0: 3.5 characters at the line's speed only; mbusd's minimum is 1)\n"
            "  -W wait    : answer wait in milliseconds (1-10000, default 500)\n"
            "  -T timeout : idle connection timeout in seconds (0-1000, default 60; 0: none)\n"
            "  -b         : reply to broadcasts (the request echoed)\n\n"
            "Configuration file (-c): mbusd's keys (loglevel logfile device speed mode enable_rs485\n"
            "trx_control trx_sysfile address port maxconn timeout retries pause wait\n"
            "replyonbroadcast), and past mbusd (rsmodbus-gateway(8)):\n"
            "  tls_cert, tls_key, tls_ca         : Modbus/TCP Security front (mutual TLS)\n"
            "  tls_address, tls_port             : where it listens (default port 802)\n"
            "  tls_role.ROLE = r|rw FIRST-LAST   : what a certificate's role may do (else exception 01)\n"
            "  rtutcp_port, udp_port             : RTU over TCP and Modbus/UDP fronts\n"
            "  backend = serial | tcp|rtutcp HOST PORT : the default line's kind\n"
            "  line.NAME = serial DEV SPEED [MODE] | tcp|rtutcp HOST PORT : another line\n"
            "  route = FIRST-LAST LINE [OFFSET]  : units to a line, remapped (no route: 0x0A)\n"
            "  status_file = PATH                : counters per line and master (Prometheus text)\n"
            "SIGHUP reloads the configuration file; connections stay.\n\n"
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
/* Set while SIGHUP's reload reads the file again: lines are not made anew. */
static int reloading;
static char config_path[256];

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
            rc = in_range("maxconn", v, 1, 10000, &cfg.maxconn);
        } else if (strcmp(k, "timeout") == 0) {
            rc = in_range("timeout", v, 0, 1000, &cfg.timeout);
        } else if (strcmp(k, "retries") == 0) {
            rc = in_range("retries", v, 0, 15, &cfg.retries);
        } else if (strcmp(k, "pause") == 0) {
            rc = in_range("pause", v, 0, 10000, &cfg.pause);
        } else if (strcmp(k, "wait") == 0) {
            rc = in_range("wait", v, 1, 10000, &cfg.wait);
        } else if (strcmp(k, "replyonbroadcast") == 0) {
            cfg.replyonbroadcast = truthy(v);
        } else if (strcmp(k, "status_file") == 0) {
            copy(cfg.status_file, sizeof cfg.status_file, v);
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
        } else if (strncmp(k, "line.", 5) == 0 && reloading) {
            /* Lines stay as they were made (a change takes a restart). */
            int j, known = 0;
            for (j = 0; j < nlines; j++) {
                known |= strcmp(lines[j].name, k + 5) == 0;
            }
            if (!known) {
                logw(1, "reload: %s is new: it takes a restart", k);
            }
        } else if (strncmp(k, "line.", 5) == 0) {
            struct line *L = &lines[nlines];
            char kind[16] = "", a[256] = "", b[16] = "", c[16] = "";
            int fields = sscanf(v, "%15s %255s %15s %15s", kind, a, b, c);
            memset(L, 0, sizeof *L);
            copy(L->name, sizeof L->name, k + 5);
            copy(L->kind, sizeof L->kind, kind);
            if (nlines == LINES_MAX || strcmp(L->name, "default") == 0) {
                rc = -1;
            } else if (strcmp(kind, "serial") == 0 && fields >= 3) {
                copy(L->device, sizeof L->device, a);
                L->speed = atoi(b);
                copy(L->mode, sizeof L->mode, fields == 4 ? c : "8N1");
                rc = L->speed > 0 ? 0 : -1;
            } else if ((strcmp(kind, "tcp") == 0 || strcmp(kind, "rtutcp") == 0) && fields == 3) {
                copy(L->host, sizeof L->host, a);
                copy(L->port, sizeof L->port, b);
            } else {
                rc = -1;
            }
            if (rc != 0) {
                fprintf(stderr,
                        "rsmodbus-gateway: %s:%d: %s must be 'serial DEVICE SPEED [MODE]', 'tcp HOST PORT' or "
                        "'rtutcp HOST PORT' (and the name not 'default')\n",
                        path, n, k);
            } else {
                nlines++;
            }
        } else if (strcmp(k, "route") == 0) {
            char name[32] = "";
            struct route *r = &routes[nroutes];
            int fields = sscanf(v, "%d-%d %31s %d", &r->first, &r->last, name, &r->offset), j;
            r->line = -1;
            for (j = 0; j < nlines; j++) {
                if (strcmp(lines[j].name, name) == 0) {
                    r->line = j;
                }
            }
            if (nroutes == ROUTES_MAX || fields < 3 || r->first < 0 || r->last > 255 || r->first > r->last ||
                r->line < 0) {
                fprintf(stderr,
                        "rsmodbus-gateway: %s:%d: route must be 'FIRST-LAST LINE [OFFSET]', LINE 'default' or a "
                        "line.NAME given before it\n",
                        path, n);
                rc = -1;
            } else {
                if (fields == 3) {
                    r->offset = 0;
                }
                nroutes++;
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

/* ---------------------------------------------------------------- fronts */

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
} G;

static volatile sig_atomic_t stopping;

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double) ts.tv_sec * 1e3 + (double) ts.tv_nsec / 1e6;
}

static struct master *master_of(struct line *L, uint64_t conn)
{
    int i;
    for (i = 0; i < L->nmasters; i++) {
        if (L->masters[i].conn == conn) {
            return &L->masters[i];
        }
    }
    /* A slot of a master with nothing queued is reused (its connection may be gone),
     * but not that of the request on the line (a retry goes back there). */
    for (i = 0; i < L->nmasters; i++) {
        if (L->masters[i].n == 0 && !(L->busy && i == L->turn)) {
            L->masters[i].conn = conn;
            L->masters[i].head = 0;
            L->masters[i].requests = L->masters[i].busy = 0;
            return &L->masters[i];
        }
    }
    if (L->nmasters == L->cap) {
        int cap = L->cap ? 2 * L->cap : 16;
        struct master *m = realloc(L->masters, (size_t) cap * sizeof *m);
        if (m == NULL) {
            return NULL;
        }
        L->masters = m;
        L->cap = cap;
    }
    memset(&L->masters[L->nmasters], 0, sizeof L->masters[0]);
    L->masters[L->nmasters].conn = conn;
    return &L->masters[L->nmasters++];
}

/* The line of `unit` and the unit it has there; NULL: no route. */
static struct line *route(int unit, int *there)
{
    int i;
    if (nroutes == 0) {
        *there = unit;
        return &lines[0];
    }
    for (i = 0; i < nroutes; i++) {
        if (unit >= routes[i].first && unit <= routes[i].last) {
            *there = unit + routes[i].offset;
            return *there >= 0 && *there <= 255 ? &lines[routes[i].line] : NULL;
        }
    }
    return NULL;
}

/* The server's raw callback: every request of every master, queued for its line. */
static int on_request(const modbus_request_info_t *ri, const uint8_t *pdu, int pdu_length, uint8_t *rsp_pdu, int rsp_max, void *user_data)
{
    int there;
    struct line *L = route(ri->unit_id, &there);
    struct master *m;
    struct request *r;
    (void) rsp_pdu;
    (void) rsp_max;
    if (L == NULL) {
        logw(3, "unit %d: no route (exception 0x0A)", ri->unit_id);
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_GATEWAY_PATH);
    }
    /* A connection id names one master across the fronts (unique in the process;
     * each UDP master has its own). */
    m = master_of(L, ri->connection_id);
    if (m == NULL || m->n == QUEUE_MAX) {
        logw(1, "master %llu: queue full, request 0x%02X refused (busy)", (unsigned long long) ri->connection_id,
             ri->function);
        if (m != NULL) {
            m->busy++;
        }
        L->exceptions++;
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
    }
    m->requests++;
    L->requests++;
    r = &m->q[(m->head + m->n) % QUEUE_MAX];
    r->id = ri->request_id;
    r->server = ((struct front *) user_data)->server;
    r->raw[0] = (uint8_t) there;
    memcpy(r->raw + 1, pdu, (size_t) pdu_length);
    r->len = pdu_length + 1;
    r->tries = 0;
    m->n++;
    logw(5, "master %llu: request 0x%02X for unit %d queued on line %s (%d waiting)",
         (unsigned long long) ri->connection_id, ri->function, ri->unit_id, L->name, m->n);
    return MODBUS_REPLY_LATER;
}

static void on_answer(modbus_t *ctx, int id, int rc, int error, void *user_data);

static int every_unit(const modbus_request_info_t *ri, int unit, void *user_data)
{
    (void) ri;
    (void) user_data;
    (void) unit;
    return 1;
}

/* Puts the next request on line L: the next master with one waiting, in turn. */
static void dispatch(struct line *L)
{
    int k;
    if (L->busy || now_ms() < L->quiet_until) {
        return;
    }
    for (k = 1; k <= L->nmasters; k++) {
        struct master *m = &L->masters[(L->turn + k) % L->nmasters];
        if (m->n == 0) {
            continue;
        }
        L->turn = (L->turn + k) % L->nmasters;
        L->current = m->q[m->head];
        m->head = (m->head + 1) % QUEUE_MAX;
        m->n--;
        break;
    }
    if (k > L->nmasters) {
        return;
    }
    L->current.tries++;
    L->busy = 1;
    if (modbus_send_raw_request_async(L->ctx, L->current.raw, L->current.len, L->rsp, on_answer, L) < 0) {
        logw(0, "line %s: cannot send (%s)", L->name, modbus_strerror(errno));
        L->busy = 0;
        modbus_server_answer_exception(L->current.server, L->current.id, MODBUS_EXCEPTION_GATEWAY_TARGET);
    }
}

/* Line L's answer (or its failure) to its current request. */
static void on_answer(modbus_t *ctx, int id, int rc, int error, void *user_data)
{
    struct line *L = user_data;
    struct request *r = &L->current;
    int h = L->header, crc = L->checksum;
    (void) ctx;
    (void) id;
    L->busy = 0;
    /* -R 0: only the RTU silence between frames (3.5 characters), none on TCP. */
    L->quiet_until = now_ms() + (cfg.pause > 0 ? cfg.pause : L->gap_ms);
    if (r->raw[0] == 0 && L->header == 1) {
        /* A broadcast: out, no answer expected; the request echoed with -b. */
        modbus_server_answer(r->server, r->id, cfg.replyonbroadcast ? r->raw + 1 : NULL,
                             cfg.replyonbroadcast ? r->len - 1 : MODBUS_REPLY_NONE);
        return;
    }
    if (rc > h + crc) {
        L->served++;
        modbus_server_answer(r->server, r->id, L->rsp + h, rc - h - crc);
        return;
    }
    if (error == EMBBADCRC || error == EMBBADDATA) {
        L->crc_errors++;
    } else {
        L->timeouts++;
    }
    if (r->tries <= cfg.retries) {
        logw(3, "line %s: unit %d, request 0x%02X: %s, try %d of %d", L->name, r->raw[0], r->raw[1],
             modbus_strerror(error), r->tries + 1, cfg.retries + 1);
        /* Again, first in line (after the pause). */
        struct request again = *r;
        struct master *m = &L->masters[L->turn];
        if (m->n < QUEUE_MAX) {
            m->head = (m->head + QUEUE_MAX - 1) % QUEUE_MAX;
            m->q[m->head] = again;
            m->n++;
            L->turn = (L->turn + L->nmasters - 1) % L->nmasters;
            return;
        }
    }
    logw(1, "line %s: unit %d, request 0x%02X: %s after %d tries", L->name, r->raw[0], r->raw[1],
         modbus_strerror(error), r->tries);
    L->exceptions++;
    modbus_server_answer_exception(r->server, r->id,
                                   error == EMBBADCRC || error == EMBBADDATA ? MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE
                                                                             : MODBUS_EXCEPTION_GATEWAY_TARGET);
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

/* Opens line L (a device on the network that cannot be reached now is connected by
 * its first request). */
static int open_line(struct line *L)
{
    int data, stop;
    char parity;
    if (strcmp(L->kind, "tcp") == 0) {
        L->ctx = modbus_new_tcp_pi(L->host, L->port);
    } else if (strcmp(L->kind, "rtutcp") == 0) {
        L->ctx = modbus_new_rtu_tcp_pi(L->host, L->port);
    } else {
        if (parse_mode(L->mode, &data, &parity, &stop, &L->ascii) != 0) {
            logw(0, "line %s: serial mode '%s' is not like 8N1 (or 7E1a for ASCII)", L->name, L->mode);
            return -1;
        }
        /* A character: a start bit, the data bits, the parity bit, the stop bits. */
        L->gap_ms = 3.5 * (1 + data + (parity != 'N') + stop) * 1000.0 / L->speed;
        L->ctx = L->ascii ? modbus_new_ascii(L->device, L->speed, parity, data, stop)
                          : modbus_new_rtu(L->device, L->speed, parity, data, stop);
    }
    if (L->ctx == NULL) {
        logw(0, "line %s: %s", L->name, modbus_strerror(errno));
        return -1;
    }
    /* What frames an answer's PDU: the header before it, the checksum after it. */
    L->header = modbus_get_header_length(L->ctx);
    L->checksum = modbus_get_checksum_length(L->ctx);
    modbus_set_response_timeout(L->ctx, (uint32_t) cfg.wait / 1000, (uint32_t) (cfg.wait % 1000) * 1000);
    /* Levels 8 and 9 trace the line's frames (libmodbus' debug output). */
    modbus_set_debug(L->ctx, cfg.loglevel >= 8);
    if (strcmp(L->kind, "serial") != 0) {
        modbus_set_error_recovery(L->ctx, MODBUS_ERROR_RECOVERY_LINK);
        if (modbus_connect(L->ctx) != 0) {
            logw(1, "line %s (%s %s:%s): %s (the first request connects again)", L->name, L->kind, L->host, L->port,
                 modbus_strerror(errno));
        }
        return 0;
    }
    if (modbus_connect(L->ctx) != 0) {
        logw(0, "line %s (%s): %s", L->name, L->device, modbus_strerror(errno));
        return -1;
    }
    return 0;
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

/* The counters, in the Prometheus text exposition format, to `status_file` (written
 * to a temporary file, then renamed: a reader never sees half of it). */
static void write_status(void)
{
    char tmp[300];
    FILE *f;
    int k, i;
    if (cfg.status_file[0] == '\0') {
        return;
    }
    snprintf(tmp, sizeof tmp, "%s.tmp", cfg.status_file);
    f = fopen(tmp, "w");
    if (f == NULL) {
        return;
    }
    fprintf(f, "# rsmodbus-gateway " VERSION "\n");
    fprintf(f, "# TYPE rsmodbus_gateway_requests_total counter\n");
    for (k = 0; k < nlines; k++) {
        struct line *L = &lines[k];
        int depth = 0;
        for (i = 0; i < L->nmasters; i++) {
            depth += L->masters[i].n;
        }
        fprintf(f, "rsmodbus_gateway_requests_total{line=\"%s\"} %ld\n", L->name, L->requests);
        fprintf(f, "rsmodbus_gateway_answers_total{line=\"%s\"} %ld\n", L->name, L->served);
        fprintf(f, "rsmodbus_gateway_timeouts_total{line=\"%s\"} %ld\n", L->name, L->timeouts);
        fprintf(f, "rsmodbus_gateway_bad_answers_total{line=\"%s\"} %ld\n", L->name, L->crc_errors);
        fprintf(f, "rsmodbus_gateway_exceptions_total{line=\"%s\"} %ld\n", L->name, L->exceptions);
        fprintf(f, "rsmodbus_gateway_queue_depth{line=\"%s\"} %d\n", L->name, depth + L->busy);
        for (i = 0; i < L->nmasters; i++) {
            struct master *m = &L->masters[i];
            if (m->requests > 0 || m->n > 0) {
                fprintf(f, "rsmodbus_gateway_master_requests_total{line=\"%s\",master=\"%llu\"} %ld\n", L->name,
                        (unsigned long long) m->conn, m->requests);
                fprintf(f, "rsmodbus_gateway_master_busy_total{line=\"%s\",master=\"%llu\"} %ld\n", L->name,
                        (unsigned long long) m->conn, m->busy);
                fprintf(f, "rsmodbus_gateway_master_queue_depth{line=\"%s\",master=\"%llu\"} %d\n", L->name,
                        (unsigned long long) m->conn, m->n);
            }
        }
    }
    fclose(f);
    rename(tmp, cfg.status_file);
}

static volatile sig_atomic_t hangup;

static void on_hangup(int sig)
{
    (void) sig;
    hangup = 1;
}

/* SIGHUP: the configuration file again, without dropping a master. The policy, the
 * routes and the line's timing (loglevel, retries, pause, wait, timeout,
 * replyonbroadcast, status_file, tls_role.*, route) take the file's values; a
 * change to what was opened (devices, lines, fronts, certificates) is logged and
 * takes a restart. A file with an error changes nothing. */
static void reload(void)
{
    struct config old = cfg;
    struct role old_roles[ROLES_MAX];
    struct route old_routes[ROUTES_MAX];
    int old_nroles = nroles, old_nroutes = nroutes, i, rc;
    if (config_path[0] == '\0') {
        logw(1, "reload: no configuration file (-c)");
        return;
    }
    memcpy(old_roles, roles, sizeof roles);
    memcpy(old_routes, routes, sizeof routes);
    nroles = 0;
    nroutes = 0;
    reloading = 1;
    rc = read_config(config_path);
    reloading = 0;
    if (rc != 0) {
        cfg = old;
        memcpy(roles, old_roles, sizeof roles);
        memcpy(routes, old_routes, sizeof routes);
        nroles = old_nroles;
        nroutes = old_nroutes;
        logw(0, "reload: %s has an error: the running configuration stays", config_path);
        return;
    }
#define KEEP(field)                                                                                                    \
    do {                                                                                                               \
        if (memcmp(&cfg.field, &old.field, sizeof cfg.field) != 0) {                                                   \
            logw(1, "reload: " #field " changed: it takes a restart");                                                \
            memcpy(&cfg.field, &old.field, sizeof cfg.field);                                                          \
        }                                                                                                              \
    } while (0)
    KEEP(logfile);
    KEEP(device);
    KEEP(speed);
    KEEP(mode);
    KEEP(rs485);
    KEEP(trx);
    KEEP(trx_sysfile);
    KEEP(address);
    KEEP(port);
    KEEP(maxconn);
    KEEP(tls_address);
    KEEP(tls_port);
    KEEP(tls_cert);
    KEEP(tls_key);
    KEEP(tls_ca);
    KEEP(rtutcp_port);
    KEEP(udp_port);
    KEEP(backend);
    KEEP(back_host);
    KEEP(back_port);
#undef KEEP
    for (i = 0; i < nlines; i++) {
        modbus_set_response_timeout(lines[i].ctx, (uint32_t) cfg.wait / 1000, (uint32_t) (cfg.wait % 1000) * 1000);
        modbus_set_debug(lines[i].ctx, cfg.loglevel >= 8);
    }
    for (i = 0; i < G.nfronts; i++) {
        modbus_server_set_idle_timeout(G.fronts[i].server, (uint32_t) cfg.timeout, 0);
    }
    logw(2, "configuration reloaded from %s: %d route(s), %d role(s)", config_path, nroutes, nroles);
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

int main(int argc, char **argv)
{
    int opt, data, stop, ascii;
    char parity;
    modbus_server_callbacks_t cb;
    char port[16];
    int i;
    double next_status = 0;

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
            copy(config_path, sizeof config_path, optarg);
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
            if (in_range("-C", optarg, 1, 10000, &cfg.maxconn) != 0) {
                return 1;
            }
            break;
        case 'N':
            if (in_range("-N", optarg, 0, 15, &cfg.retries) != 0) {
                return 1;
            }
            break;
        case 'R':
            if (in_range("-R", optarg, 0, 10000, &cfg.pause) != 0) {
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
    if (parse_mode(cfg.mode, &data, &parity, &stop, &ascii) != 0) {
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

    /* The lines: the default one (the device, or `backend`), and those of `line.*`. */
    {
        struct line *L0 = &lines[0];
        copy(L0->kind, sizeof L0->kind, cfg.backend);
        copy(L0->device, sizeof L0->device, cfg.device);
        copy(L0->mode, sizeof L0->mode, cfg.mode);
        copy(L0->host, sizeof L0->host, cfg.back_host);
        copy(L0->port, sizeof L0->port, cfg.back_port);
        L0->speed = cfg.speed;
    }
    for (i = 0; i < nlines; i++) {
        if (open_line(&lines[i]) != 0) {
            return 1;
        }
    }
    if (cfg.rs485 && modbus_rtu_set_serial_mode(lines[0].ctx, MODBUS_RTU_RS485) != 0) {
        logw(0, "line %s: RS-485 mode: %s", cfg.device, modbus_strerror(errno));
        return 1;
    }
    if (cfg.trx == 1 || cfg.trx == 2) {
        if (modbus_rtu_set_rts(lines[0].ctx, cfg.trx == 1 ? MODBUS_RTU_RTS_UP : MODBUS_RTU_RTS_DOWN) != 0) {
            logw(0, "line %s: RS-485 direction by RTS (-t, -r): %s (a serial RTU line only)", lines[0].name,
                 modbus_strerror(errno));
            return 1;
        }
    } else if (cfg.trx >= 3) {
        /* The direction through a sysfs file (a GPIO's value): written before and after
         * each transmission, by the library's RTS hook. -y writes 1 while sending, -Y 0. */
        int fd = open(cfg.trx_sysfile, O_WRONLY | O_CLOEXEC);
        if (fd < 0) {
            logw(0, "RS-485 direction file %s: %s", cfg.trx_sysfile, strerror(errno));
            return 1;
        }
        close(fd);
        if (modbus_rtu_set_custom_rts(lines[0].ctx, sysfs_direction) != 0 ||
            modbus_rtu_set_rts(lines[0].ctx, cfg.trx == 3 ? MODBUS_RTU_RTS_UP : MODBUS_RTU_RTS_DOWN) != 0) {
            logw(0, "line %s: RS-485 direction through %s (-y, -Y): %s (a serial RTU line only)", lines[0].name,
                 cfg.trx_sysfile, modbus_strerror(errno));
            return 1;
        }
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
    signal(SIGHUP, on_hangup);
    logw(2, "rsmodbus-gateway " VERSION " started: %s:%d -> %s %d %s%s", cfg.address, cfg.port, cfg.device,
         cfg.speed, cfg.mode, lines[0].ascii ? " (ASCII)" : "");

    while (!stopping) {
        struct pollfd pfd[FRONTS_MAX + LINES_MAX];
        double timeout = -1; /* ms; the pause after a fast serial line is below one */
        int failed = 0, k;
        double now = now_ms();
        struct timespec ts;
        for (i = 0; i < G.nfronts; i++) {
            pfd[i].fd = modbus_server_get_fd(G.fronts[i].server);
            pfd[i].events = POLLIN;
        }
        for (k = 0; k < nlines; k++) {
            struct line *L = &lines[k];
            int lt;
            double t;
            modbus_get_pollfd(L->ctx, &pfd[G.nfronts + k], &lt);
            t = lt;
            if (!L->busy && L->quiet_until > now) {
                double pause = L->quiet_until - now;
                t = t < 0 || pause < t ? pause : t;
            }
            if (t >= 0 && (timeout < 0 || t < timeout)) {
                timeout = t;
            }
        }
        if (cfg.status_file[0] != '\0' && (timeout < 0 || timeout > 1000)) {
            timeout = 1000;
        }
        if (now >= next_status) {
            write_status();
            next_status = now + 1000;
        }
        ts.tv_sec = (time_t) (timeout / 1000);
        ts.tv_nsec = (long) ((timeout - (double) ts.tv_sec * 1000) * 1e6);
        if (ppoll(pfd, (nfds_t) (G.nfronts + nlines), timeout < 0 ? NULL : &ts, NULL) < 0 && errno != EINTR) {
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
        if (hangup) {
            hangup = 0;
            reload();
        }
        for (k = 0; k < nlines; k++) {
            struct line *L = &lines[k];
            if (pfd[G.nfronts + k].fd >= 0 || modbus_pending(L->ctx) > 0) {
                modbus_process(L->ctx, pfd[G.nfronts + k].revents);
            }
            dispatch(L);
        }
    }
    for (i = 0; i < nlines; i++) {
        logw(2, "line %s: %ld answers, %ld timeouts, %ld bad answers", lines[i].name, lines[i].served,
             lines[i].timeouts, lines[i].crc_errors);
    }
    write_status();
    logw(2, "rsmodbus-gateway stopped");
    /* The lines first: modbus_free runs the callback of a request still on a line
     * (ESHUTDOWN after the close), which answers its master through its front. */
    for (i = 0; i < nlines; i++) {
        modbus_close(lines[i].ctx);
        modbus_free(lines[i].ctx);
        free(lines[i].masters);
    }
    for (i = 0; i < G.nfronts; i++) {
        modbus_server_free(G.fronts[i].server);
        modbus_free(G.fronts[i].ctx);
    }
    return 0;
}
