/*
 * mbtest-server: the Modbus server used by the differential client scenarios.
 *
 * SPDX-License-Identifier: MIT OR Apache-2.0
 *
 * It is built against Debian's libmodbus and run WITHOUT our LD_LIBRARY_PATH (the runner
 * sets EXPECT_LIB=debian, enforced by the libinfo constructor), so that every client
 * scenario talks to the reference implementation. Its debug log is compared between
 * the run of a scenario with Debian's client library and the run with ours: it is an
 * independent witness of the bytes our client puts on the wire.
 *
 * usage: mbtest-server tcp   <ip>     <port|0> <readyfile>
 *        mbtest-server tcppi <node>   <port|0> <readyfile>
 *        mbtest-server rtu   <device> <slave>  <readyfile>
 * The ready file receives the TCP port (useful with port 0) or "rtu" once the server
 * listens / has opened the device. Many TCP clients may connect, one after the other or
 * at the same time; the mapping persists for the server's life (one run of a scenario).
 *
 * Mapping: coils 0..63, discrete inputs 0..63, holding registers 0..127, input registers
 * 0..63, all with deterministic initial values. Special behaviours, keyed by address
 * (outside the mapping), exercise client error paths:
 *
 *   FC03 read holding registers at
 *     0x1000+c  exception response with code c (0..15)
 *     0x1010    exception with a mismatched function code (0x84)
 *     0x1011    exception with a bad CRC (RTU; TCP: plain exception code 2)
 *     0x1020    normal reply after 500 ms
 *     0x1021    normal reply written one byte every 50 ms
 *     0x1022    first 4 bytes, then 400 ms, then the rest
 *     0x1030    wrong TID (TCP) / reply from slave+1 with a valid CRC (RTU)
 *     0x1031    protocol id 0x0001 (TCP; RTU: normal)
 *     0x1032    protocol id 0x0101 (TCP; RTU: normal)
 *     0x1033    protocol id 0x0100 (TCP; RTU: normal)
 *     0x1034    unit id + 1 (TCP) / slave 0 in the reply (RTU)
 *     0x1035    bad CRC (RTU; TCP: normal)
 *     0x1036    bad CRC and slave+1 (RTU; TCP: normal)
 *     0x1040    wrong function code (0x04) in a well-formed reply
 *     0x1041    byte count and data for nb-1 registers
 *     0x1042    byte count 0xFF (too many data), only header+fc+count sent
 *     0x1043    half a reply, then the connection is closed (RTU: nothing more)
 *     0x1044    12 bytes of garbage
 *     0x1045    no reply at all
 *     0x1046    the reply is sent twice
 *     0x1047    the reply followed by 3 extra bytes
 *     0x1048    byte count nb*2+1 with that many data bytes
 *   writes at 0x1200/0x1201 (FC05, 06, 0F, 10, 16) get a reply whose address, value or
 *   quantity echo is wrong (see handle_write_special); FC17 reading at 0x1200 gets a
 *   byte count for nb-1 registers.
 *   FC16 at 0xFF00: a text marker from the client (mbt_diff_begin/end); printed and
 *   acknowledged.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <netinet/in.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include <modbus.h>

#include "../common/mbtest.h"

#define MAX_CLIENTS 32

static int backend_rtu;
static int header_length;

static void on_term(int sig)
{
    (void) sig;
    fflush(stdout);
    fflush(stderr);
    _exit(0);
}

/* Options for a hand-built reply. */
struct raw_opts {
    int tid_delta;
    int proto;
    int unit_delta;
    int bad_crc;
    int byte_gap_ms;
    int split_at;
    int split_ms;
    int truncate_to;
    int extra_bytes;
    int twice;
};

static int write_all(int fd, const uint8_t *buf, int len)
{
    int done = 0;
    while (done < len) {
        ssize_t rc;
        if (backend_rtu) {
            rc = write(fd, buf + done, (size_t) (len - done));
        } else {
            rc = send(fd, buf + done, (size_t) (len - done), MSG_NOSIGNAL);
        }
        if (rc < 0) {
            if (errno == EINTR) {
                continue;
            }
            return -1;
        }
        done += (int) rc;
    }
    return 0;
}

/* Builds the ADU for `pdu` in answer to query `q` and writes it as requested. */
static void send_raw(int fd, const uint8_t *q, const uint8_t *pdu, int pdu_len,
                     const struct raw_opts *o)
{
    uint8_t adu[600];
    int len = 0, i, copies;

    if (backend_rtu) {
        uint16_t crc;
        adu[len++] = (uint8_t) (q[0] + o->unit_delta);
        memcpy(adu + len, pdu, (size_t) pdu_len);
        len += pdu_len;
        crc = mbt_crc16(adu, len);
        if (o->bad_crc) {
            crc ^= 0x5A5A;
        }
        adu[len++] = (uint8_t) (crc & 0xFF);
        adu[len++] = (uint8_t) (crc >> 8);
    } else {
        int tid = ((q[0] << 8) | q[1]) + o->tid_delta;
        adu[len++] = (uint8_t) (tid >> 8);
        adu[len++] = (uint8_t) tid;
        adu[len++] = (uint8_t) (o->proto >> 8);
        adu[len++] = (uint8_t) o->proto;
        adu[len++] = (uint8_t) ((pdu_len + 1) >> 8);
        adu[len++] = (uint8_t) (pdu_len + 1);
        adu[len++] = (uint8_t) (q[6] + o->unit_delta);
        memcpy(adu + len, pdu, (size_t) pdu_len);
        len += pdu_len;
    }
    for (i = 0; i < o->extra_bytes; i++) {
        adu[len++] = (uint8_t) (0xE0 + i);
    }
    if (o->truncate_to > 0 && o->truncate_to < len) {
        len = o->truncate_to;
    }

    printf("RAW-REPLY");
    for (i = 0; i < len; i++) {
        printf("[%.2X]", adu[i]);
    }
    printf("\n");
    fflush(stdout);

    for (copies = 0; copies < (o->twice ? 2 : 1); copies++) {
        if (o->byte_gap_ms > 0) {
            for (i = 0; i < len; i++) {
                if (i > 0) {
                    mbt_msleep(o->byte_gap_ms);
                }
                if (write_all(fd, adu + i, 1) < 0) {
                    return;
                }
            }
        } else if (o->split_at > 0 && o->split_at < len) {
            if (write_all(fd, adu, o->split_at) < 0) {
                return;
            }
            mbt_msleep(o->split_ms);
            write_all(fd, adu + o->split_at, len - o->split_at);
        } else {
            write_all(fd, adu, len);
        }
    }
}

/* A well-formed FC03 reply carrying values addr, addr+1, ... */
static int build_read_reply(uint8_t *pdu, int addr, int nb, int bytecount_nb)
{
    int i, len = 0;
    pdu[len++] = 0x03;
    pdu[len++] = (uint8_t) (bytecount_nb * 2);
    for (i = 0; i < bytecount_nb; i++) {
        pdu[len++] = (uint8_t) ((addr + i) >> 8);
        pdu[len++] = (uint8_t) (addr + i);
    }
    (void) nb;
    return len;
}

/* Returns 1 if the connection must be closed after this request, 0 otherwise. */
static int handle_read_special(int fd, const uint8_t *q, int addr, int nb)
{
    uint8_t pdu[300];
    int pdu_len;
    struct raw_opts o;

    memset(&o, 0, sizeof(o));
    if (nb < 1 || nb > 125) {
        nb = 1;
    }
    pdu_len = build_read_reply(pdu, addr, nb, nb);

    if (addr >= 0x1000 && addr <= 0x100F) {
        printf("special: exception code %d\n", addr - 0x1000);
        pdu[0] = 0x83;
        pdu[1] = (uint8_t) (addr - 0x1000);
        pdu_len = 2;
    } else {
        switch (addr) {
        case 0x1010:
            printf("special: exception with mismatched function code\n");
            pdu[0] = 0x84;
            pdu[1] = 0x02;
            pdu_len = 2;
            break;
        case 0x1011:
            printf("special: exception with bad CRC\n");
            pdu[0] = 0x83;
            pdu[1] = 0x02;
            pdu_len = 2;
            o.bad_crc = 1;
            break;
        case 0x1020:
            printf("special: sleep 500 ms before replying\n");
            fflush(stdout);
            mbt_msleep(500);
            break;
        case 0x1021:
            printf("special: one byte every 50 ms\n");
            o.byte_gap_ms = 50;
            break;
        case 0x1022:
            printf("special: 4 bytes, 400 ms pause, rest\n");
            o.split_at = 4;
            o.split_ms = 400;
            break;
        case 0x1030:
            printf("special: wrong TID / slave\n");
            if (backend_rtu) {
                o.unit_delta = 1;
            } else {
                o.tid_delta = 1;
            }
            break;
        case 0x1031:
            printf("special: protocol id 0x0001\n");
            o.proto = 0x0001;
            break;
        case 0x1032:
            printf("special: protocol id 0x0101\n");
            o.proto = 0x0101;
            break;
        case 0x1033:
            printf("special: protocol id 0x0100\n");
            o.proto = 0x0100;
            break;
        case 0x1034:
            printf("special: unit id + 1 / slave 0\n");
            o.unit_delta = backend_rtu ? -q[0] : 1;
            break;
        case 0x1035:
            printf("special: bad CRC\n");
            o.bad_crc = 1;
            break;
        case 0x1036:
            printf("special: bad CRC and wrong slave\n");
            o.bad_crc = 1;
            o.unit_delta = 1;
            break;
        case 0x1040:
            printf("special: wrong function code\n");
            pdu[0] = 0x04;
            break;
        case 0x1041:
            printf("special: data for nb-1 registers\n");
            pdu_len = build_read_reply(pdu, addr, nb, nb - 1);
            break;
        case 0x1042:
            printf("special: byte count 0xFF\n");
            pdu[1] = 0xFF;
            pdu_len = 2;
            break;
        case 0x1043:
            printf("special: half a reply then close\n");
            o.truncate_to = backend_rtu ? 3 : 5;
            send_raw(fd, q, pdu, pdu_len, &o);
            return backend_rtu ? 0 : 1;
        case 0x1044: {
            static const uint8_t garbage[12] = {0xDE, 0xAD, 0xBE, 0xEF, 0x00, 0x03, 0x17,
                                                0x42, 0x99, 0x01, 0x02, 0x03};
            int i;
            printf("special: garbage\nRAW-REPLY");
            for (i = 0; i < 12; i++) {
                printf("[%.2X]", garbage[i]);
            }
            printf("\n");
            fflush(stdout);
            write_all(fd, garbage, 12);
            return 0;
        }
        case 0x1045:
            printf("special: no reply\n");
            return 0;
        case 0x1046:
            printf("special: reply twice\n");
            o.twice = 1;
            break;
        case 0x1047:
            printf("special: 3 extra bytes\n");
            o.extra_bytes = 3;
            break;
        case 0x1048: {
            int i;
            printf("special: odd byte count\n");
            pdu[1] = (uint8_t) (nb * 2 + 1);
            for (i = 0; i < nb * 2 + 1; i++) {
                pdu[2 + i] = (uint8_t) (0x10 + i);
            }
            pdu_len = 2 + nb * 2 + 1;
            break;
        }
        default:
            printf("special: unknown special address 0x%X, exception 2\n", addr);
            pdu[0] = 0x83;
            pdu[1] = 0x02;
            pdu_len = 2;
            break;
        }
    }
    send_raw(fd, q, pdu, pdu_len, &o);
    return 0;
}

static void handle_write_special(int fd, const uint8_t *q, int fc, int addr)
{
    uint8_t pdu[16];
    struct raw_opts o;
    const uint8_t *p = q + header_length;
    int variant = addr & 1;

    memset(&o, 0, sizeof(o));
    /* Echo of fc, addr(2), value/qty(2) [+ and/or masks for FC16]. */
    memcpy(pdu, p, 5);
    if (fc == 0x16) {
        memcpy(pdu, p, 7);
    }
    switch (fc) {
    case 0x05:
        if (variant == 0) {
            printf("special: write_bit echo with address+1\n");
            pdu[2]++;
        } else {
            printf("special: write_bit echo with another value\n");
            pdu[3] = (uint8_t) (pdu[3] == 0xFF ? 0x00 : 0xFF);
        }
        break;
    case 0x06:
        if (variant == 0) {
            printf("special: write_register echo with value+1\n");
            pdu[4]++;
        } else {
            printf("special: write_register echo with address+1\n");
            pdu[2]++;
        }
        break;
    case 0x0F:
    case 0x10:
        if (variant == 0) {
            printf("special: write multiple reply with address+1\n");
            pdu[2]++;
        } else {
            printf("special: write multiple reply with quantity+1\n");
            pdu[4]++;
        }
        break;
    case 0x16:
        printf("special: mask write echo with another and-mask\n");
        pdu[4] ^= 0xFF;
        send_raw(fd, q, pdu, 7, &o);
        return;
    default:
        break;
    }
    send_raw(fd, q, pdu, 5, &o);
}

static void handle_marker(int fd, const uint8_t *q)
{
    const uint8_t *p = q + header_length;
    int nb = (p[3] << 8) | p[4];
    int bytes = p[5];
    char text[256];
    int i, n = 0;
    uint8_t pdu[5];
    struct raw_opts o;

    for (i = 0; i < bytes && i < nb * 2 && n < (int) sizeof(text) - 1; i++) {
        char c = (char) p[6 + i];
        if (c == '\0') {
            break;
        }
        text[n++] = c;
    }
    text[n] = '\0';
    if (strncmp(text, "BEGIN ", 6) == 0) {
        printf("DIFF-OK-BEGIN %s\n", text + 6);
        fprintf(stderr, "DIFF-OK-BEGIN %s\n", text + 6);
    } else if (strncmp(text, "END ", 4) == 0) {
        printf("DIFF-OK-END %s\n", text + 4);
        fprintf(stderr, "DIFF-OK-END %s\n", text + 4);
    } else {
        printf("MARK %s\n", text);
    }
    memcpy(pdu, p, 5);
    memset(&o, 0, sizeof(o));
    send_raw(fd, q, pdu, 5, &o);
}

/* Returns 1 if the connection must be closed. */
static int handle(modbus_t *ctx, int fd, uint8_t *q, int rc, modbus_mapping_t *map)
{
    int fc = q[header_length];
    int addr = (q[header_length + 1] << 8) | q[header_length + 2];
    int nb = (q[header_length + 3] << 8) | q[header_length + 4];

    if (rc > 0 && fc == 0x10 && addr == 0xFF00) {
        handle_marker(fd, q);
        return 0;
    }
    if (rc > 0 && fc == 0x03 && addr >= 0x1000 && addr < 0x1100) {
        return handle_read_special(fd, q, addr, nb);
    }
    if (rc > 0 && (fc == 0x05 || fc == 0x06 || fc == 0x0F || fc == 0x10 || fc == 0x16) &&
        (addr == 0x1200 || addr == 0x1201)) {
        handle_write_special(fd, q, fc, addr);
        return 0;
    }
    if (rc > 0 && fc == 0x17 && addr == 0x1200) {
        uint8_t pdu[300];
        struct raw_opts o;
        int len;
        memset(&o, 0, sizeof(o));
        printf("special: write_and_read reply for nb-1 registers\n");
        len = build_read_reply(pdu, addr, nb, nb > 1 ? nb - 1 : 0);
        pdu[0] = 0x17;
        send_raw(fd, q, pdu, len, &o);
        return 0;
    }
    if (modbus_reply(ctx, q, rc, map) == -1) {
        printf("modbus_reply failed: %s\n", modbus_strerror(errno));
    }
    return 0;
}

static void init_mapping(modbus_mapping_t *map)
{
    int i;
    for (i = 0; i < map->nb_bits; i++) {
        map->tab_bits[i] = (uint8_t) ((i % 3) == 0);
    }
    for (i = 0; i < map->nb_input_bits; i++) {
        map->tab_input_bits[i] = (uint8_t) ((i * 7 + 3) % 5 < 2);
    }
    for (i = 0; i < map->nb_registers; i++) {
        map->tab_registers[i] = (uint16_t) (0x0100 + i * 3);
    }
    for (i = 0; i < map->nb_input_registers; i++) {
        map->tab_input_registers[i] = (uint16_t) (0xA000 + i);
    }
}

static void write_ready(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    if (f != NULL) {
        fputs(text, f);
        fclose(f);
    }
}

/* Serves the clients that are readable: those in `ready`, or (poll != 0) those readable
 * right now. A client whose connection fails or must be closed is removed. */
static void service_clients(modbus_t *ctx, modbus_mapping_t *map, int *clients, int *nclients,
                            fd_set *ready, int poll)
{
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    fd_set now;
    int i;

    if (poll) {
        struct timeval tv = {0, 0};
        int maxfd = -1;
        FD_ZERO(&now);
        for (i = 0; i < *nclients; i++) {
            FD_SET(clients[i], &now);
            if (clients[i] > maxfd) {
                maxfd = clients[i];
            }
        }
        if (maxfd < 0 || select(maxfd + 1, &now, NULL, NULL, &tv) <= 0) {
            return;
        }
        ready = &now;
    }
    for (i = 0; i < *nclients; i++) {
        int rc, fd = clients[i];
        if (!FD_ISSET(fd, ready)) {
            continue;
        }
        modbus_set_socket(ctx, fd);
        rc = modbus_receive(ctx, query);
        if (rc > 0 && handle(ctx, fd, query, rc, map) == 0) {
            continue;
        }
        if (rc == -1) {
            printf("client gone: %s\n", modbus_strerror(errno));
        } else {
            printf("closing the client connection\n");
            shutdown(fd, SHUT_RDWR);
        }
        close(fd);
        FD_CLR(fd, ready);
        clients[i] = clients[--*nclients];
        i--;
    }
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    modbus_mapping_t *map;
    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    int is_pi = 0;

    if (argc != 5) {
        fprintf(stderr, "usage: %s tcp|tcppi <ip/node> <port> <ready> | rtu <dev> <slave> <ready>\n",
                argv[0]);
        return 1;
    }
    signal(SIGTERM, on_term);
    signal(SIGINT, on_term);
    signal(SIGPIPE, SIG_IGN);
    setvbuf(stdout, NULL, _IOLBF, 0);

    if (strcmp(argv[1], "rtu") == 0) {
        backend_rtu = 1;
        ctx = modbus_new_rtu(argv[2], 115200, 'N', 8, 1);
        if (ctx != NULL) {
            modbus_set_slave(ctx, atoi(argv[3]));
        }
    } else if (strcmp(argv[1], "tcppi") == 0) {
        is_pi = 1;
        ctx = modbus_new_tcp_pi(argv[2], argv[3]);
    } else {
        ctx = modbus_new_tcp(argv[2], atoi(argv[3]));
    }
    if (ctx == NULL) {
        fprintf(stderr, "cannot create the context: %s\n", modbus_strerror(errno));
        return 1;
    }
    header_length = modbus_get_header_length(ctx);
    modbus_set_debug(ctx, TRUE);
    /* modbus_reply sleeps this long before flushing on some exceptions: keep it short. */
    modbus_set_response_timeout(ctx, 0, 100000);

    map = modbus_mapping_new_start_address(0, 64, 0, 64, 0, 128, 0, 64);
    if (map == NULL) {
        fprintf(stderr, "cannot allocate the mapping\n");
        return 1;
    }
    init_mapping(map);

    if (backend_rtu) {
        int fd;
        if (modbus_connect(ctx) == -1) {
            fprintf(stderr, "cannot open %s: %s\n", argv[2], modbus_strerror(errno));
            return 1;
        }
        fd = modbus_get_socket(ctx);
        write_ready(argv[4], "rtu\n");
        for (;;) {
            int rc = modbus_receive(ctx, query);
            if (rc == 0) {
                continue;
            }
            if (rc == -1 && errno != EMBBADCRC) {
                printf("receive error: %s\n", modbus_strerror(errno));
                continue;
            }
            handle(ctx, fd, query, rc, map);
        }
    } else {
        int listen_fd, port = 0, i, nclients = 0;
        int clients[MAX_CLIENTS];
        char buf[32];
        struct sockaddr_storage ss;
        socklen_t sl = sizeof(ss);

        listen_fd = is_pi ? modbus_tcp_pi_listen(ctx, 8) : modbus_tcp_listen(ctx, 8);
        if (listen_fd == -1) {
            fprintf(stderr, "cannot listen: %s\n", modbus_strerror(errno));
            return 1;
        }
        if (getsockname(listen_fd, (struct sockaddr *) &ss, &sl) == 0) {
            if (ss.ss_family == AF_INET) {
                port = ntohs(((struct sockaddr_in *) &ss)->sin_port);
            } else {
                port = ntohs(((struct sockaddr_in6 *) &ss)->sin6_port);
            }
        }
        snprintf(buf, sizeof(buf), "%d\n", port);
        write_ready(argv[4], buf);

        for (;;) {
            fd_set rset;
            int maxfd = listen_fd;
            FD_ZERO(&rset);
            FD_SET(listen_fd, &rset);
            for (i = 0; i < nclients; i++) {
                FD_SET(clients[i], &rset);
                if (clients[i] > maxfd) {
                    maxfd = clients[i];
                }
            }
            if (select(maxfd + 1, &rset, NULL, NULL, NULL) < 0) {
                if (errno == EINTR) {
                    continue;
                }
                perror("select");
                return 1;
            }
            if (FD_ISSET(listen_fd, &rset)) {
                int s = listen_fd, nfd;
                /* A client that closes and reconnects at once: let its FIN land and
                 * serve the old connection first, so that the log order is stable. */
                mbt_msleep(20);
                service_clients(ctx, map, clients, &nclients, NULL, 1);
                nfd = is_pi ? modbus_tcp_pi_accept(ctx, &s) : modbus_tcp_accept(ctx, &s);
                if (nfd >= 0) {
                    if (nclients < MAX_CLIENTS) {
                        clients[nclients++] = nfd;
                    } else {
                        close(nfd);
                    }
                }
                continue;
            }
            service_clients(ctx, map, clients, &nclients, &rset, 0);
        }
    }
    return 0;
}
