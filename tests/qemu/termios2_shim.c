/* Test fixture, not shipped: preloaded into the ARM build under Debian's user-mode QEMU 10.0,
 * which does not translate the termios2 ioctls (TCGETS2, TCSETS2, TCSETSW2, TCSETSF2) that a
 * real ARM Linux kernel has; serial2 sets a port's bit rate only through them. Each is served
 * with its plain termios counterpart, and the speed the program set is kept per descriptor and
 * reported back, as a kernel's pseudo-terminal does (a pseudo-terminal's speed moves no byte
 * faster or slower). Every other ioctl goes to the kernel untouched.
 *
 *   aarch64-linux-gnu-gcc -shared -fPIC -O2 -o termios2_shim.so termios2_shim.c
 *   qemu-aarch64 -E LD_PRELOAD=termios2_shim.so bin/robodeploy dxl scan --port /dev/pts/N …
 */
#include <asm/ioctls.h>
#include <asm/termbits.h>
#include <stdarg.h>
#include <string.h>
#include <sys/syscall.h>
#include <unistd.h>

int ioctl(int fd, unsigned long request, ...);

/* What each descriptor was last set to: the speed bits of c_cflag and the two speeds. */
#define TRACKED 1024
static struct {
    int set;
    tcflag_t speed_bits;
    speed_t ispeed, ospeed;
} speeds[TRACKED];

static const tcflag_t SPEED_BITS = CBAUD | (CBAUD << IBSHIFT);

int ioctl(int fd, unsigned long request, ...) {
    va_list args;
    va_start(args, request);
    void *arg = va_arg(args, void *);
    va_end(args);

    unsigned long plain;
    switch (request) {
    case TCGETS2: {
        struct termios t;
        long r = syscall(SYS_ioctl, fd, TCGETS, &t);
        if (r != 0) {
            return (int)r;
        }
        struct termios2 *t2 = arg;
        memset(t2, 0, sizeof *t2);
        memcpy(t2, &t, sizeof t); /* termios2 is termios with the two speeds after it */
        if (fd >= 0 && fd < TRACKED && speeds[fd].set) {
            t2->c_cflag = (t2->c_cflag & ~SPEED_BITS) | speeds[fd].speed_bits;
            t2->c_ispeed = speeds[fd].ispeed;
            t2->c_ospeed = speeds[fd].ospeed;
        } else {
            t2->c_ispeed = t2->c_ospeed = 38400;
        }
        return 0;
    }
    case TCSETS2:
        plain = TCSETS;
        break;
    case TCSETSW2:
        plain = TCSETSW;
        break;
    case TCSETSF2:
        plain = TCSETSF;
        break;
    default:
        return (int)syscall(SYS_ioctl, fd, request, arg);
    }
    const struct termios2 *t2 = arg;
    struct termios t;
    memcpy(&t, t2, sizeof t);
    t.c_cflag = (t.c_cflag & ~SPEED_BITS) | B38400;
    long r = syscall(SYS_ioctl, fd, plain, &t);
    if (r == 0 && fd >= 0 && fd < TRACKED) {
        speeds[fd].set = 1;
        speeds[fd].speed_bits = t2->c_cflag & SPEED_BITS;
        speeds[fd].ispeed = t2->c_ispeed;
        speeds[fd].ospeed = t2->c_ospeed;
    }
    return (int)r;
}
