/*
 * baromapd-tap: a device's port read by a small process of its own, which stamps every read.
 *
 * The same process as daemon/baromapd/tap.py's serve() and main(), in C. Why a tap at all is in
 * tap.py's docstring (a reader thread of the daemon waits for the GIL before it can take the
 * time, so its stamps are late by whatever held it). Why a C one: the tap wakes for every packet
 * the port delivers (four a scan from the twins, 300 and more a second at 500 kbaud), and per
 * wake-up the Python tap interprets its loop and allocates a few objects, and carries a whole
 * interpreter (14 MB resident) for a loop that needs a few kilobytes. This one does the same
 * system calls and nothing else.
 *
 * The protocol is tap.py's, byte for byte (tests/daemon/test_daemon_tap.py runs both):
 * - argv: the port's descriptor (inherited) and the device's name;
 * - stdout (the data pipe, nothing else is ever written there): records of a little-endian
 *   int64 (CLOCK_MONOTONIC ns at which the read returned) and uint32 (byte count), the bytes
 *   after them ("<qI" in tap.RECORD); a record with stamp -1 and no bytes answers a flush;
 * - stdin (the daemon's requests): 'F' drops everything read and not yet forwarded and is
 *   answered by the flush record; any other byte followed by a little-endian uint32 sets the
 *   frame size ("<cI", tap.EXPECT) at which the bytes held are handed over at once;
 * - bytes are handed over in one write when a frame's worth is held, or after QUIET_MS without
 *   more, or, while no frame size is known, once the oldest held is HOLD_MS old; when idle the
 *   tap looks every IDLE_MS whether its parent is still there;
 * - exit 0 when the port hangs up (a read of nothing), stdin closes, the parent is gone, or on
 *   SIGINT (Python's KeyboardInterrupt); exit 1 when the port or a pipe fails (EIO: unplugged;
 *   EPIPE: the daemon went away) or at a bad command line (the only text, on stderr).
 *
 * Two cases tap.py gets wrong the same way are handled here as there: a read that finds nothing
 * (EAGAIN: the daemon's tcflush between poll and read, the port being non-blocking) is not a
 * failure, and an interrupted call is retried.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

enum {
    RECORD_BYTES = 12,       /* tap.RECORD: int64 stamp, uint32 length */
    EXPECT_BYTES = 5,        /* tap.EXPECT: one byte, uint32 frame size */
    QUIET_MS = 4,            /* tap.QUIET_MS: why 4 is argued there */
    HOLD_MS = 20,            /* tap.HOLD_MS: a line that never goes quiet, no frame size said */
    PRIORITY = 10,           /* tap.PRIORITY, within RLIMIT_RTPRIO */
    IDLE_MS = 1000,          /* tap.IDLE_MS */
    READ_CHUNK = 65536,      /* tap.READ_CHUNK */
    PIPE_BYTES = 1 << 20,    /* tap.PIPE_BYTES */
    CONTROL_CHUNK = 4096,    /* what tap.py reads of stdin at once */
    NAME_BYTES = 16,         /* the kernel keeps 15 bytes of a thread's name, and a NUL */
};

static const char FLUSH_REQUEST = 'F';
static const int64_t FLUSHED = -1;

/*
 * Records not yet handed over. Each read goes straight into it, after room for its header: the
 * only buffer the loop uses, allocated once. Its size is the pipe's: a hand-over larger than
 * that would wait for the daemon anyway. Only the pages the reads reach become resident (a
 * scan's worth, as the tap hands each frame over); tap.py's list has no bound, and when this
 * one has no room for a whole READ_CHUNK it hands over early, which only splits a write.
 */
static unsigned char pending[PIPE_BYTES];

static void put_le(unsigned char *to, uint64_t value, int bytes)
{
    for (int i = 0; i < bytes; i++)
        to[i] = (unsigned char)(value >> (8 * i));
}

static uint32_t get_le32(const unsigned char *from)
{
    return (uint32_t)from[0] | (uint32_t)from[1] << 8 | (uint32_t)from[2] << 16 |
           (uint32_t)from[3] << 24;
}

static int64_t monotonic_ns(void)
{
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (int64_t)now.tv_sec * 1000000000 + now.tv_nsec;
}

/* All of it, as Python's os.write on a blocking pipe; false when the pipe failed. */
static bool write_all(int fd, const unsigned char *data, size_t size)
{
    while (size > 0) {
        ssize_t done = write(fd, data, size);
        if (done < 0) {
            if (errno == EINTR)
                continue;
            return false;
        }
        data += done;
        size -= (size_t)done;
    }
    return true;
}

static void on_interrupt(int signal_number)
{
    (void)signal_number;
    _exit(0);
}

/* tap.serve(): read `port` until it hangs up; records to `out`; requests on `control`. */
static int serve(int port, int out, int control)
{
    int flags = fcntl(control, F_GETFL);
    if (flags < 0 || fcntl(control, F_SETFL, flags | O_NONBLOCK) < 0)
        return 1;
    pid_t parent = getppid();
    unsigned char requests[CONTROL_CHUNK + EXPECT_BYTES - 1];
    size_t requested = 0;
    uint32_t frame = 0;  /* bytes in one of the device's frames, as last said (0: unknown) */
    uint64_t held = 0;   /* bytes read and not yet forwarded */
    int64_t first = 0;   /* when the oldest of them was read */
    size_t used = 0;     /* bytes of pending[] in use */
    bool unquiet = false; /* bytes read since the last hand-over (tap.py: `pending` not empty) */

    for (;;) {
        struct pollfd fds[2] = {{control, POLLIN, 0}, {port, POLLIN, 0}};
        int ready = poll(fds, 2, unquiet ? QUIET_MS : IDLE_MS);
        if (ready < 0) {
            if (errno == EINTR)
                continue;
            return 1;
        }
        if (ready == 0) {
            if (unquiet) {
                if (!write_all(out, pending, used))
                    return 1;
                used = 0;
                unquiet = false;
                held = 0; /* the line went quiet: the next bytes start a frame */
            } else if (getppid() != parent) {
                return 0;
            }
            continue;
        }
        if (fds[0].revents) { /* a request first, as tap.py */
            ssize_t size = read(control, requests + requested, CONTROL_CHUNK);
            if (size == 0)
                return 0; /* the daemon closed the port */
            if (size < 0 && errno != EAGAIN && errno != EINTR)
                return 1;
            requested += size > 0 ? (size_t)size : 0;
            size_t at = 0;
            while (at < requested) {
                if (requests[at] == FLUSH_REQUEST) {
                    at += 1;
                    used = 0;
                    unquiet = false;
                    held = 0;
                    unsigned char answer[RECORD_BYTES];
                    put_le(answer, (uint64_t)FLUSHED, 8);
                    put_le(answer + 8, 0, 4);
                    if (!write_all(out, answer, sizeof answer))
                        return 1;
                } else if (requested - at >= EXPECT_BYTES) {
                    frame = get_le32(requests + at + 1);
                    at += EXPECT_BYTES;
                } else {
                    break;
                }
            }
            memmove(requests, requests + at, requested - at);
            requested -= at;
        }
        if (fds[1].revents) {
            if (PIPE_BYTES - used < RECORD_BYTES + READ_CHUNK) {
                if (!write_all(out, pending, used)) /* no room: hand over early (see pending) */
                    return 1;
                used = 0;
            }
            unsigned char *record = pending + used;
            ssize_t size = read(port, record + RECORD_BYTES, READ_CHUNK);
            int64_t stamp = monotonic_ns();
            if (size == 0)
                return 0; /* hang-up */
            if (size < 0) {
                if (errno == EAGAIN || errno == EINTR)
                    continue; /* flushed between poll and read */
                return 1;     /* EIO: unplugged */
            }
            put_le(record, (uint64_t)stamp, 8);
            put_le(record + 8, (uint64_t)size, 4);
            if (!unquiet)
                first = stamp;
            used += RECORD_BYTES + (size_t)size;
            unquiet = true;
            held += (uint64_t)size;
            bool whole = frame && held >= frame; /* the daemon need not wait for quiet */
            bool stale = !frame && stamp - first >= (int64_t)HOLD_MS * 1000000;
            if (whole || stale) {
                if (!write_all(out, pending, used))
                    return 1;
                used = 0;
                unquiet = false;
                held = whole ? held % frame : 0; /* what came of the next frame already */
            }
        }
    }
}

/* tap.realtime(): SCHED_FIFO if RLIMIT_RTPRIO allows (the unit's LimitRTPRIO=); else not. */
static void realtime(void)
{
    struct rlimit limit;
    if (getrlimit(RLIMIT_RTPRIO, &limit) != 0 || limit.rlim_cur == 0)
        return;
    int priority = PRIORITY;
    if (limit.rlim_cur != RLIM_INFINITY && limit.rlim_cur < (rlim_t)PRIORITY)
        priority = (int)limit.rlim_cur;
    struct sched_param param = {.sched_priority = priority};
    (void)sched_setscheduler(0, SCHED_FIFO, &param);
}

int main(int argc, char **argv)
{
    char *end = NULL;
    long port = argc == 3 ? strtol(argv[1], &end, 10) : -1;
    if (argc != 3 || end == argv[1] || *end != '\0' || port < 0 || port > INT32_MAX) {
        fprintf(stderr, "usage: %s FD NAME  (started by the daemon with FD passed to it)\n",
                argv[0]);
        return 1;
    }
    /* Python ignores SIGPIPE (a write to a closed pipe fails with EPIPE: exit 1) and turns
     * SIGINT into KeyboardInterrupt (exit 0) from its start; the same here. */
    signal(SIGPIPE, SIG_IGN);
    struct sigaction interrupt = {.sa_handler = on_interrupt};
    sigaction(SIGINT, &interrupt, NULL);
    (void)prctl(PR_SET_PDEATHSIG, SIGKILL, 0, 0, 0);
    char name[NAME_BYTES];
    snprintf(name, sizeof name, "baromapd-tap-%s", argv[2]); /* cut to 15 bytes, as tap.py */
    (void)prctl(PR_SET_NAME, name, 0, 0, 0);
    realtime();
    (void)fcntl(STDOUT_FILENO, F_SETPIPE_SZ, PIPE_BYTES);
    return serve((int)port, STDOUT_FILENO, STDIN_FILENO);
}
