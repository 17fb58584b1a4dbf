/* The C echo of benchmarks/bench_ethercat.py (target: "paced SOEM p99 <= 2x the C echo's p99
 * measured in the same run"): the floor of a round trip over the veth pair, with no interpreter.
 *
 * It does what the bench's Python Echo does, in C: an AF_PACKET raw socket bound to the given
 * interface for the EtherCAT ethertype 0x88A4, busy-polled (non-blocking receive in a loop), each
 * received frame read whole and sent back out of the same interface unchanged, the way a segment
 * whose last port is closed returns a frame (no slave here processes the datagrams, so the
 * working counters come back as they went out); frames this socket sent itself (PACKET_OUTGOING)
 * are skipped. Pinned to the CPU given (default 1, as the emulator's wire thread).
 *
 * Usage: echo IFACE [CPU]. Prints "ready" once bound, and "echoed N" when SIGTERM/SIGINT ends it.
 * Built by the bench at run time with the C compiler the package build uses (cc -O2).
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <linux/if_ether.h>
#include <linux/if_packet.h>
#include <net/if.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#define ETHERTYPE_ETHERCAT 0x88A4

static volatile sig_atomic_t running = 1;

static void stop(int sig) {
    (void)sig;
    running = 0;
}

static void pin(int cpu) {
    long cpus = sysconf(_SC_NPROCESSORS_CONF);
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpus > 0 ? cpu % (int)cpus : 0, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0)
        perror("echo: sched_setaffinity (running unpinned)");
}

int main(int argc, char **argv) {
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s IFACE [CPU]\n", argv[0]);
        return 2;
    }
    pin(argc == 3 ? atoi(argv[2]) : 1);
    unsigned int ifindex = if_nametoindex(argv[1]);
    if (ifindex == 0) {
        perror("echo: if_nametoindex");
        return 1;
    }
    int fd = socket(AF_PACKET, SOCK_RAW, htons(ETHERTYPE_ETHERCAT));
    if (fd < 0) {
        perror("echo: socket");
        return 1;
    }
    struct sockaddr_ll addr;
    memset(&addr, 0, sizeof addr);
    addr.sll_family = AF_PACKET;
    addr.sll_protocol = htons(ETHERTYPE_ETHERCAT);
    addr.sll_ifindex = (int)ifindex;
    if (bind(fd, (struct sockaddr *)&addr, sizeof addr) != 0) {
        perror("echo: bind");
        return 1;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = stop;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    printf("ready\n");
    fflush(stdout);

    unsigned char buf[2048];
    unsigned long echoed = 0, failed = 0;
    while (running) {
        struct sockaddr_ll from;
        socklen_t fromlen = sizeof from;
        ssize_t n = recvfrom(fd, buf, sizeof buf, MSG_DONTWAIT, (struct sockaddr *)&from, &fromlen);
        if (n < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)
                continue;
            perror("echo: recvfrom");
            return 1;
        }
        if (from.sll_pkttype == PACKET_OUTGOING)
            continue;
        if (send(fd, buf, (size_t)n, 0) == n)
            echoed++;
        else
            failed++;
    }
    printf("echoed %lu failed %lu\n", echoed, failed);
    close(fd);
    return 0;
}
