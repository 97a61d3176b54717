/* Deadline wait and send for the setpoint streamer (companion/aio/streamer.py).
 *
 * Called through ctypes, which releases the Python GIL for the duration of each call, so the
 * sender thread waits for a deadline and puts the datagram on the wire without needing the
 * interpreter: a busy asyncio thread (telemetry decoding) cannot delay the send.
 *
 * Time is CLOCK_MONOTONIC in nanoseconds, the clock behind Python's time.monotonic() on Linux.
 * spin_ns >= 0: sleep (absolute clock_nanosleep) until deadline - spin_ns, then busy-wait.
 * spin_ns < 0: busy-wait the whole way (for a dedicated core: on virtual machines a halted
 * vCPU can take milliseconds to wake, which no sleep-based wait avoids).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>

int64_t ecca_now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + (int64_t)ts.tv_nsec;
}

/* Timer slack of the calling thread [ns] (Linux default 50 us); 0 on success, else errno. */
int ecca_set_timer_slack_ns(unsigned long slack_ns)
{
    return prctl(PR_SET_TIMERSLACK, slack_ns, 0UL, 0UL, 0UL) == 0 ? 0 : errno;
}

/* Wait until deadline_ns (see the file comment); returns the clock reading after the wait,
 * never earlier than deadline_ns. */
int64_t ecca_wait_until(int64_t deadline_ns, int64_t spin_ns)
{
    int64_t now = ecca_now_ns();
    if (spin_ns >= 0 && deadline_ns - spin_ns > now) {
        int64_t wake = deadline_ns - spin_ns;
        struct timespec ts;
        ts.tv_sec = (time_t)(wake / 1000000000LL);
        ts.tv_nsec = (long)(wake % 1000000000LL);
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {
        }
        now = ecca_now_ns();
    }
    while (now < deadline_ns) {
        now = ecca_now_ns();
    }
    return now;
}

/* Wait until deadline_ns, then send len bytes of buf on fd: sendto() to addr when addrlen > 0,
 * else send(). Returns the clock reading taken just before the send; *err is 0 or the errno of
 * a failed or short send. */
int64_t ecca_wait_send(int64_t deadline_ns, int64_t spin_ns, int fd, const void *buf, size_t len,
                       const void *addr, uint32_t addrlen, int *err)
{
    int64_t t = ecca_wait_until(deadline_ns, spin_ns);
    ssize_t n;
    do {
        n = addrlen > 0 ? sendto(fd, buf, len, MSG_DONTWAIT, (const struct sockaddr *)addr,
                                 (socklen_t)addrlen)
                        : send(fd, buf, len, MSG_DONTWAIT);
    } while (n < 0 && errno == EINTR);
    *err = n < 0 ? errno : ((size_t)n == len ? 0 : EMSGSIZE);
    return t;
}
