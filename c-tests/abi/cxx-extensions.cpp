// cxx-extensions.cpp: a C++ program on rsmodbus' extensions, the way an application
// written in C++ uses them. c-tests/suites/abi-check.sh compiles it as C++11 and C++17
// with -Wall -Wextra -Werror -pedantic against include/ and runs it.
//
// In one process, on loopback (an ephemeral port):
//   - a server that runs itself (modbus_server_new) on a thread of its own, answering
//     through a modbus_server_callbacks_t whose functions are C++ (extern "C");
//   - an event-driven client: modbus_read_registers_async, then modbus_get_pollfd,
//     poll() and modbus_process until its modbus_callback_t has run;
//   - two more clients behind one multi handle (modbus_multi_*): a write and a read in
//     flight at once, completed by modbus_multi_perform; modbus_multi_wakeup;
//   - the other public types of the extensions (modbus_request_info_t,
//     modbus_device_id_object_t, modbus_tls_authorize_t) used from C++.
// It prints which libmodbus.so.5 the loader mapped ("LOADED path (rsmodbus version)"),
// one "ok   - " / "FAIL - " line per check and "N passed, M failed"; exit 0 when all
// passed.
//
// SPDX-License-Identifier: MIT OR Apache-2.0

#include <modbus.h>
#include <modbus-rtu.h>
#include <modbus-tcp.h>
#include <modbus-tls.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <thread>

#include "libpath.h"

namespace {

int passed = 0;
int failed = 0;

void check(bool cond, const char *what, const char *detail = "")
{
    if (cond) {
        passed++;
    } else {
        failed++;
    }
    std::printf("%s%s%s%s\n", cond ? "ok   - " : "FAIL - ", what, *detail ? ": " : "", detail);
    std::fflush(stdout);
}

const int NB = 16;

// The server's data. The callbacks run on the runner's thread only; main() reads the
// counters after joining it.
struct Device {
    uint16_t registers[NB];
    int reads;
    int writes;
};

// One request's completion, as its modbus_callback_t saw it.
struct Completion {
    bool done;
    int rc;
    int error;
};

double seconds_since(std::chrono::steady_clock::time_point t0)
{
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

} // namespace

// The library calls these through C function pointers: they have C linkage.
extern "C" {

static int read_registers(const modbus_request_info_t *ri, int addr, int nb, uint16_t *dest,
                          void *user_data)
{
    Device *d = static_cast<Device *>(user_data);
    if (addr < 0 || nb < 1 || addr + nb > NB) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    for (int i = 0; i < nb; i++) {
        // Input registers are the holding registers plus 1000.
        dest[i] = static_cast<uint16_t>(d->registers[addr + i] +
                                        (ri->function == MODBUS_FC_READ_INPUT_REGISTERS ? 1000 : 0));
    }
    d->reads++;
    return 0;
}

static int write_registers(const modbus_request_info_t *ri, int addr, int nb, const uint16_t *src,
                           void *user_data)
{
    Device *d = static_cast<Device *>(user_data);
    if (addr < 0 || nb < 1 || addr + nb > NB || ri->unit_id < 0) {
        return MODBUS_REPLY_EXCEPTION(MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
    }
    std::memcpy(d->registers + addr, src, sizeof(uint16_t) * static_cast<size_t>(nb));
    d->writes++;
    return 0;
}

static void on_done(modbus_t *ctx, int request_id, int rc, int error, void *user_data)
{
    Completion *c = static_cast<Completion *>(user_data);
    (void) ctx;
    (void) request_id;
    c->done = true;
    c->rc = rc;
    c->error = error;
}

static int authorize(modbus_t *ctx, const char *role, int unit_id, int function, int address,
                     int nb, void *user_data)
{
    (void) ctx;
    (void) unit_id;
    (void) address;
    (void) nb;
    (void) user_data;
    return role != NULL && function == MODBUS_FC_READ_HOLDING_REGISTERS;
}

} // extern "C"

int main()
{
    std::printf("LOADED %s (rsmodbus %s)\n", mbt_mapped_libmodbus("(not mapped)"), rsmodbus_version());
    std::printf("compiled as C++ %ld\n", static_cast<long>(__cplusplus));

    // --- the server, on a thread of its own ------------------------------------------
    Device device;
    std::memset(&device, 0, sizeof device);
    for (int i = 0; i < NB; i++) {
        device.registers[i] = static_cast<uint16_t>(100 + i);
    }
    modbus_t *srv_ctx = modbus_new_tcp("127.0.0.1", 0);
    int listen_fd = srv_ctx != NULL ? modbus_tcp_listen(srv_ctx, 4) : -1;
    struct sockaddr_in addr;
    socklen_t addr_len = sizeof addr;
    if (listen_fd < 0 || getsockname(listen_fd, reinterpret_cast<struct sockaddr *>(&addr), &addr_len) != 0) {
        check(false, "server listens on loopback", modbus_strerror(errno));
        return 1;
    }
    int port = ntohs(addr.sin_port);
    modbus_set_socket(srv_ctx, listen_fd);
    modbus_server_t *server = modbus_server_new(srv_ctx, 4);
    check(server != NULL, "modbus_server_new", server == NULL ? modbus_strerror(errno) : "");
    if (server == NULL) {
        return 1;
    }
    modbus_server_callbacks_t cb;
    std::memset(&cb, 0, sizeof cb);
    cb.struct_size = sizeof cb;
    cb.read_registers = read_registers;
    cb.write_registers = write_registers;
    check(modbus_server_set_callbacks(server, &cb, &device) == 0, "modbus_server_set_callbacks");
    std::thread runner([server] { modbus_server_run(server, -1); });

    // --- event-driven client: submit, then poll + process ----------------------------
    modbus_t *client = modbus_new_tcp("127.0.0.1", port);
    modbus_set_response_timeout(client, 2, 0);
    uint16_t regs[4] = {0, 0, 0, 0};
    Completion read_done = {false, 0, 0};
    int id = modbus_read_registers_async(client, 2, 4, regs, on_done, &read_done);
    check(id >= 0, "modbus_read_registers_async submits", id < 0 ? modbus_strerror(errno) : "");
    std::chrono::steady_clock::time_point t0 = std::chrono::steady_clock::now();
    while (id >= 0 && !read_done.done && seconds_since(t0) < 5) {
        struct pollfd pfd;
        int timeout_ms = -1;
        if (modbus_get_pollfd(client, &pfd, &timeout_ms) == -1) {
            pfd.fd = -1;
            pfd.events = 0;
        }
        // Bounded, so that a missed wake-up costs time, not the test.
        if (timeout_ms < 0 || timeout_ms > 100) {
            timeout_ms = 100;
        }
        pfd.revents = 0;
        if (poll(&pfd, 1, timeout_ms) < 0 && errno != EINTR) {
            break;
        }
        if (modbus_process(client, pfd.revents) == -1 && errno != EAGAIN) {
            check(false, "modbus_process", modbus_strerror(errno));
            break;
        }
    }
    check(read_done.done && read_done.rc == 4, "the async read completed with rc 4",
          read_done.done ? (read_done.rc == 4 ? "" : modbus_strerror(read_done.error)) : "no completion within 5 s");
    check(regs[0] == 102 && regs[3] == 105, "the async read got the server's registers 102..105");
    check(modbus_pending(client) == 0, "nothing pending after the completion");

    // --- two clients behind one multi handle -----------------------------------------
    modbus_multi_t *multi = modbus_multi_new();
    modbus_t *writer = modbus_new_tcp("127.0.0.1", port);
    modbus_t *reader = modbus_new_tcp("127.0.0.1", port);
    check(multi != NULL && modbus_multi_add(multi, writer) == 0 && modbus_multi_add(multi, reader) == 0,
          "modbus_multi_new and modbus_multi_add of two contexts");
    check(modbus_multi_get_fd(multi) >= 0, "modbus_multi_get_fd gives a descriptor");
    uint16_t input[2] = {0, 0};
    Completion write_done = {false, 0, 0};
    Completion input_done = {false, 0, 0};
    int wid = modbus_write_register_async(writer, 9, 0x1234, on_done, &write_done);
    int rid = modbus_read_input_registers_async(reader, 0, 2, input, on_done, &input_done);
    check(wid >= 0 && rid >= 0, "a write and a read submitted on the multi's contexts");
    t0 = std::chrono::steady_clock::now();
    while (wid >= 0 && rid >= 0 && !(write_done.done && input_done.done) && seconds_since(t0) < 5) {
        if (modbus_multi_perform(multi, 100) == -1 && errno != EINTR) {
            check(false, "modbus_multi_perform", modbus_strerror(errno));
            break;
        }
    }
    check(write_done.done && write_done.rc == 1, "the multi's write completed with rc 1");
    check(input_done.done && input_done.rc == 2 && input[0] == 1100 && input[1] == 1101,
          "the multi's read of input registers got 1100, 1101");
    // A wake-up given while none waits ends the next wait at once.
    t0 = std::chrono::steady_clock::now();
    check(modbus_multi_wakeup(multi) == 0 && modbus_multi_perform(multi, 5000) == 0 && seconds_since(t0) < 1,
          "modbus_multi_wakeup ends the next modbus_multi_perform at once");

    // --- the other public types, from C++ --------------------------------------------
    modbus_device_id_object_t object;
    std::memset(&object, 0, sizeof object);
    check(sizeof object.value == 256, "modbus_device_id_object_t holds a 256-byte value");
    modbus_tls_authorize_t policy = authorize;
    modbus_t *tls = modbus_new_tcp_tls("127.0.0.1", MODBUS_TCP_SECURITY_DEFAULT_PORT);
    check(tls != NULL && modbus_set_tls_authorization(tls, policy, NULL) == 0,
          "modbus_set_tls_authorization takes a C++ modbus_tls_authorize_t");
    modbus_free(tls);

    // --- the end: stop the runner from this thread, then free ------------------------
    modbus_multi_free(multi);
    modbus_free(writer);
    modbus_free(reader);
    modbus_free(client);
    check(modbus_server_stop(server) == 0, "modbus_server_stop from another thread");
    runner.join();
    check(device.reads == 2 && device.writes == 1, "the server's callbacks ran: 2 reads, 1 write");
    check(device.registers[9] == 0x1234, "the write reached the server's registers");
    modbus_server_free(server);
    modbus_free(srv_ctx);

    std::printf("%d passed, %d failed\n", passed, failed);
    return failed == 0 ? 0 : 1;
}
