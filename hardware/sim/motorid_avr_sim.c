/*
 * motorid-avr-sim: run the bench firmware (an ATmega328P ELF) in simavr, with a simulated
 * DC motor and quadrature encoder wired to it and UART0 bridged to a pseudo-terminal.
 *
 *   motorid-avr-sim FIRMWARE.elf [--a 25] [--b 3] [--friction 0] [--counts-per-rev 16667]
 *                   [--encoder-rate COUNTS_PER_S] [--driver dir-pwm|in1-in2]
 *                   [--speed 1.0] [--substep-cycles 16] [--boot-delay 0.05] [--lockstep-fd FD]
 *
 * Two clocks.  In real time (the default) it prints "PTY <path>" on stdout once the
 * pseudo-terminal exists, starts the AVR when the host opens it (after --boot-delay s, as an Uno
 * resets when its port is opened) and runs against the wall clock (--speed below).  With
 * --lockstep-fd FD (a connected stream socket it inherits) it prints "LOCKSTEP" and the emulated
 * time moves only when the host grants it (the lock-step exchange below), so what the firmware
 * sees does not depend on how fast either process runs.  Either way it runs until SIGTERM or
 * SIGINT, or until the process that started it is gone (its parent pid changes: a parent killed
 * by SIGKILL cannot stop it; in lock-step also when the host closes its socket), and prints one
 * "STATS ..." line on stdout when it stops. SIGUSR1 hangs the firmware (an endless loop with
 * interrupts on) to test the AVR watchdog.
 *
 * The lock-step exchange (little-endian): the host sends a grant, `until_cycle u64,
 * stop_on_frame u32, id u32, n u32` and n bytes for the UART; the harness queues the bytes as input (fed
 * to the UART as its XON/XOFF allows, so they arrive at the cycle the grant starts), runs the AVR
 * until its cycle count reaches until_cycle (to the end of the instruction or sleep that crosses
 * it), or, with stop_on_frame, until the AVR has sent a frame delimiter (0x00), or until 60 kB of
 * output wait, and answers `cycle u64, state u32 (simavr's cpu state), id u32 (the grant's), n u32`
 * and the n bytes the AVR sent meanwhile.  A grant below the current cycle only delivers its bytes.  The host's bytes
 * thus reach the firmware at an emulated instant fixed by the exchange, never by the wall clock.
 *
 * The motor  d omega/dt = -a omega + b u - c sign(omega)  is integrated exactly (zero-order
 * hold) over sub-steps of --substep-cycles CPU cycles (default 16 = 1 us). The drive u is read
 * at each sub-step from the firmware's registers, because simavr 1.6 does not emulate the PWM
 * waveform on the pin: u = +-OCR2A (pin 11, Timer 2) with the sign from the DIR pin (8), or
 * from IN1/IN2 (8/9). Each write to those registers is watched (simavr's register IRQs), so a
 * sub-step that saw the drive change is split at the CPU cycle of the write: the motor sees every
 * change at the cycle the firmware made it. (Holding a change from the middle of its sub-step,
 * as the harness once did, put it up to half a sub-step from the write, by the same amount in
 * every period, since a tick comes at the same phase of the sub-steps.) A change no write
 * announced (STATS counts them; none is known) is held from the sub-step's middle.
 * A PWM pin that is not an output (during reset) reads as 0, as the pull-down on the real board
 * makes it. The encoder A/B inputs (pins 2/3) get one quadrature edge per sub-step at most, at
 * the CPU cycle the shaft angle crosses a count boundary (extrapolated from the sub-step's start
 * at its speed, which 1 us cannot change measurably), so a pin read sees the count of the shaft
 * at that cycle, up to 1 M counts/s.
 *
 * --encoder-rate R ignores the motor and turns the encoder at exactly R counts/s (4x counts):
 * that is how the firmware's encoder ceiling is measured.
 *
 * Time in real-time mode: simavr runs free, faster than real time on a desktop. The host times its HEARTBEATs on
 * the wall clock while the firmware's host-silence watchdog counts emulated time, so an
 * emulation running more than 4x faster than the wall clock would starve the watchdog. --speed
 * caps emulated time at that multiple of the wall clock (default 1.0: emulated time never runs
 * ahead of real time, so wall-clock heartbeats arrive at least as often as on a real board);
 * --speed 0 runs free.
 *
 * An AVR reset (the hardware watchdog, or a jump to 0) clears simavr's cycle timers: the main
 * loop checks every few thousand instructions that the motor timer is still registered and
 * registers it again if not.
 *
 * The UART bridge is the harness's own, single-threaded: bytes from the AVR are queued and
 * written to the pty without blocking, bytes from the host are fed to the UART as its XON/XOFF
 * allows, and while more than 4 kB wait for a busy host the emulation pauses, so nothing is
 * lost. (simavr's uart_pty part drops output when the host lags, and can hang on exit.)
 */
#define _GNU_SOURCE
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <stdint.h>
#include <sys/socket.h>
#include <termios.h>

#include <simavr/avr_ioport.h>
#include <simavr/sim_interrupts.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_irq.h>

/* ATmega328P data-space addresses */
#define REG_PINB 0x23
#define REG_DDRB 0x24
#define REG_PORTB 0x25
#define REG_PIND 0x29
#define REG_PCIFR 0x3B
#define REG_PORTD 0x2B
#define REG_DDRD 0x2A
#define REG_MCUSR 0x54
#define REG_SPL 0x5D
#define REG_SPH 0x5E
#define REG_TCCR2A 0xB0
#define REG_OCR2A 0xB3
#define BIT_COM2A1 7

#define PWM_BIT 3       /* pin 11 = PB3 (OC2A) */
#define DIR_BIT 0       /* pin 8 = PB0: DIR, or IN1 */
#define IN2_BIT 1       /* pin 9 = PB1 */
#define ENC_A_PIN 2     /* PD2 */
#define ENC_B_PIN 3     /* PD3 */

enum driver { DRIVER_DIR_PWM, DRIVER_IN1_IN2 };

/* A register write that changed the drive: from this CPU cycle on the motor sees `drive`. */
typedef struct drive_change {
    avr_cycle_count_t cycle;
    double drive;
} drive_change_t;

#define MAX_DRIVE_CHANGES 16   /* per sub-step; the firmware writes at most 3 drive registers per tick */
#define N_DRIVE_REGISTERS 4

struct harness;
/* One watched drive register: which, and the harness it reports to. */
typedef struct drive_watch {
    struct harness *s;
    uint16_t address;
} drive_watch_t;

typedef struct harness {
    avr_t *avr;
    avr_irq_t *enc_a, *enc_b;
    enum driver driver;
    double a, b, friction, counts_per_rev, encoder_rate;
    uint32_t substep;
    /* exact ZOH coefficients over one sub-step, precomputed */
    double h, e, one_minus_e_over_a, h_minus_over_a;
    double last_drive;   /* the drive at the end of the previous sub-step */
    drive_change_t changes[MAX_DRIVE_CHANGES];   /* written since, in cycle order */
    int n_changes;
    double written_drive; /* the drive of the registers after the last change written */
    drive_watch_t watches[N_DRIVE_REGISTERS];
    uint64_t unwatched_changes; /* drive changes no register write announced (held from mid sub-step) */
    int edge_direction;  /* the edge scheduled inside this sub-step: +1, -1, or 0 for none */
    double speed;        /* rad/s */
    double position;     /* shaft angle in counts (4x) */
    int64_t emitted;     /* count the A/B pins currently show */
    int last_a, last_b;
    uint64_t edges;
    uint64_t resets;
    uint16_t min_sp;     /* lowest stack pointer seen (sampled every sub-step) */
    uint64_t flow_pauses; /* 0.2 ms waits for the host to take the AVR's output */
} harness_t;

static volatile sig_atomic_t stop_requested = 0;
static volatile sig_atomic_t hang_requested = 0;

static void on_signal(int sig) {
    (void)sig;
    stop_requested = 1;
}

static void on_hang(int sig) {
    (void)sig;
    hang_requested = 1;
}

/* The process that started the harness; when it dies the harness is handed to another (init or
   a subreaper), so a changed parent pid means nobody will ever stop it: stop on our own. */
static pid_t parent_pid = 0;

static int should_stop(void) {
    if (!stop_requested && getppid() != parent_pid) stop_requested = 1;
    return stop_requested;
}

/* Test hook (SIGUSR1): send the CPU into "rjmp ." at the top of the application flash with
   interrupts left on, as a firmware bug that hangs loop() would. Interrupts keep running; the
   AVR watchdog, no longer fed, resets the chip. */
#define HANG_ADDRESS 0x7000
static void hang_firmware(avr_t *avr) {
    avr->flash[HANG_ADDRESS] = 0xFF;       /* rjmp .-2 = 0xCFFF, little-endian */
    avr->flash[HANG_ADDRESS + 1] = 0xCF;
    avr->pc = HANG_ADDRESS;
}

static const uint16_t DRIVE_REGISTERS[N_DRIVE_REGISTERS] = {REG_DDRB, REG_PORTB, REG_TCCR2A, REG_OCR2A};

/* The drive the registers give, with `value` in place of register `address` (0: none). */
static double drive_with(const harness_t *s, uint16_t address, uint8_t value) {
    const uint8_t *d = s->avr->data;
    uint8_t ddrb = address == REG_DDRB ? value : d[REG_DDRB];
    uint8_t portb = address == REG_PORTB ? value : d[REG_PORTB];
    uint8_t tccr2a = address == REG_TCCR2A ? value : d[REG_TCCR2A];
    uint8_t ocr2a = address == REG_OCR2A ? value : d[REG_OCR2A];
    if (!(ddrb & (1 << PWM_BIT))) return 0.0;                  /* floating: pull-down */
    double magnitude;
    if (tccr2a & (1 << BIT_COM2A1)) magnitude = ocr2a;
    else magnitude = (portb & (1 << PWM_BIT)) ? 255.0 : 0.0;
    int dir = (portb >> DIR_BIT) & 1;
    if (s->driver == DRIVER_DIR_PWM) return dir ? magnitude : -magnitude;
    int in2 = (portb >> IN2_BIT) & 1;
    if (dir == in2) return 0.0;                               /* brake or coast */
    return dir ? magnitude : -magnitude;
}

static double drive(const harness_t *s) { return drive_with(s, 0, 0); }

/* A drive register written (before or after simavr stores it: the value is substituted): a
   change of the drive is queued with the cycle of the write. */
static void on_drive_write(struct avr_irq_t *irq, uint32_t value, void *param) {
    drive_watch_t *w = param;
    harness_t *s = w->s;
    (void)irq;
    double u = drive_with(s, w->address, (uint8_t)value);
    if (u == s->written_drive || s->n_changes == MAX_DRIVE_CHANGES) return;
    s->changes[s->n_changes].cycle = s->avr->cycle;
    s->changes[s->n_changes].drive = u;
    s->n_changes++;
    s->written_drive = u;
}

/* PCIFR is write-one-to-clear on the chip: a 1 clears that pin-change flag and so its pending
   interrupt. simavr 1.6 has no handler for it and stores the byte written, so a firmware that
   clears a flag itself (having counted an edge without its interrupt) would get the interrupt
   anyway, and the flag set instead of cleared. */
static void on_pcifr_write(avr_t *avr, avr_io_addr_t address, uint8_t value, void *param) {
    (void)param;
    for (int i = 0; i < avr->interrupts.vector_count; i++) {
        avr_int_vector_t *vector = avr->interrupts.vector[i];
        if (vector->raised.reg == address && (value & (1 << vector->raised.bit))) {
            avr_clear_interrupt(avr, vector);
            avr->data[address] &= ~(1 << vector->raised.bit);
        }
    }
}

static void watch_drive_registers(harness_t *s) {
    for (int i = 0; i < N_DRIVE_REGISTERS; i++) {
        s->watches[i].s = s;
        s->watches[i].address = DRIVE_REGISTERS[i];
        avr_irq_register_notify(avr_iomem_getirq(s->avr, DRIVE_REGISTERS[i], NULL, AVR_IOMEM_IRQ_ALL),
                                on_drive_write, &s->watches[i]);
    }
}

static void set_encoder_pins(harness_t *s) {
    static const int A[4] = {0, 1, 1, 0}, B[4] = {0, 0, 1, 1};
    int q = (int)(s->emitted & 3);
    if (A[q] != s->last_a) { s->last_a = A[q]; avr_raise_irq(s->enc_a, A[q]); }
    if (B[q] != s->last_b) { s->last_b = B[q]; avr_raise_irq(s->enc_b, B[q]); }
}

/* The motor over a step of dt s at constant drive u, given e = exp(-a dt), p = (1 - e) / a and
   q = dt - p. */
static void advance_exact(harness_t *s, double u, double e, double p, double q) {
    const double to_counts = s->counts_per_rev / (2.0 * M_PI);
    double force = s->b * u;
    double w = s->speed;
    if (s->friction > 0.0) {
        if (w == 0.0 && fabs(force) <= s->friction) return;   /* stuck */
        double sign = w != 0.0 ? (w > 0 ? 1.0 : -1.0) : (force > 0 ? 1.0 : -1.0);
        force -= s->friction * sign;
    }
    double target = force / s->a;                             /* steady state of this step */
    double w_next = e * w + target * (1.0 - e);
    double angle = p * w + target * q;
    if (s->friction > 0.0 && w != 0.0 && (w_next > 0) != (w > 0)) {
        /* speed crosses zero inside the step: stop there (friction holds it if it can) */
        w_next = 0.0;
    }
    s->speed = w_next;
    s->position += angle * to_counts;
}

/* The motor over `cycles` CPU cycles at constant drive u. */
static void advance(harness_t *s, double u, avr_cycle_count_t cycles) {
    if (cycles == 0) return;
    if (cycles == s->substep) { advance_exact(s, u, s->e, s->one_minus_e_over_a, s->h_minus_over_a); return; }
    double dt = cycles / (double)s->avr->frequency;
    double e = exp(-s->a * dt);
    advance_exact(s, u, e, (1.0 - e) / s->a, dt - (1.0 - e) / s->a);
}

/* The motor over the sub-step (when - substep, when]: each drive from the cycle it was written. */
static void integrate(harness_t *s, avr_cycle_count_t when) {
    if (s->encoder_rate != 0.0) {
        s->position += s->encoder_rate * s->h;
        s->n_changes = 0;
        return;
    }
    avr_cycle_count_t start = when - s->substep, at = start;
    double u = s->last_drive;
    int used = 0;
    while (used < s->n_changes && s->changes[used].cycle <= when) {
        avr_cycle_count_t c = s->changes[used].cycle > at ? s->changes[used].cycle : at;
        advance(s, u, c - at);
        at = c;
        u = s->changes[used++].drive;
    }
    /* writes after `when` (the timer fires at the end of an instruction) belong to the next one */
    memmove(s->changes, s->changes + used, (size_t)(s->n_changes - used) * sizeof(s->changes[0]));
    s->n_changes -= used;
    double now = drive(s);
    double expected = s->n_changes ? s->changes[s->n_changes - 1].drive : u;
    if (now != expected) {
        /* a change no write announced: from the middle of the sub-step */
        s->unwatched_changes++;
        avr_cycle_count_t middle = start + s->substep / 2;
        if (middle > at) { advance(s, u, middle - at); at = middle; }
        u = now;
        s->n_changes = 0;
        s->written_drive = now;
    }
    advance(s, u, when - at);
    s->last_drive = u;
}

/* Whether the firmware is between the two writes of a stack-pointer change: GCC moves SP by
   "out SPH; (sei or out SREG;) out SPL", so until SPL is written SP reads as the new high byte
   with the old low byte, up to 255 bytes deeper than the stack ever is when the change crosses
   a 256-byte boundary.  Pending when an "out 0x3d (SPL), r" is at the instruction about to run
   or among the two after it. */
static int stack_pointer_half_written(const avr_t *avr) {
    for (avr_flashaddr_t a = avr->pc; a <= avr->pc + 4 && a + 1 <= avr->flashend; a += 2) {
        uint16_t op = avr->flash[a] | (avr->flash[a + 1] << 8);
        if ((op & 0xF800) == 0xB800 && (((op >> 5) & 0x30) | (op & 0x0F)) == 0x3D) return 1;
    }
    return 0;
}

/* The edge scheduled by motor_step, at the cycle its count boundary is crossed. */
static avr_cycle_count_t encoder_edge(avr_t *avr, avr_cycle_count_t when, void *param) {
    harness_t *s = param;
    (void)avr; (void)when;
    if (s->edge_direction) {
        s->emitted += s->edge_direction;
        s->edge_direction = 0;
        s->edges++;
        set_encoder_pins(s);
    }
    return 0;
}

/* The pins show floor(angle) in counts: an edge due and not shown is shown now (a reversal, or
   faster than one count per sub-step), and the next boundary crossed inside the coming sub-step
   gets its edge at the cycle of the crossing. */
static void schedule_edge(harness_t *s, avr_cycle_count_t when) {
    double rate = s->encoder_rate != 0.0 ? s->encoder_rate : s->speed * s->counts_per_rev / (2.0 * M_PI);
    avr_cycle_timer_cancel(s->avr, encoder_edge, s);
    s->edge_direction = 0;
    int64_t target = (int64_t)floor(s->position);
    if (target != s->emitted) {
        s->emitted += target > s->emitted ? 1 : -1;           /* one edge per sub-step */
        s->edges++;
        set_encoder_pins(s);
        return;
    }
    if (rate == 0.0) return;
    double distance = rate > 0 ? (double)(s->emitted + 1) - s->position : s->position - (double)s->emitted;
    double cycles = ceil(distance / fabs(rate) * s->avr->frequency);
    if (cycles >= s->substep) return;                          /* not inside this sub-step */
    avr_cycle_count_t at = when + (avr_cycle_count_t)(cycles > 0 ? cycles : 0);
    s->edge_direction = rate > 0 ? 1 : -1;
    if (at <= s->avr->cycle) { encoder_edge(s->avr, at, s); return; }
    avr_cycle_timer_register(s->avr, at - s->avr->cycle, encoder_edge, s);
}

static avr_cycle_count_t motor_step(avr_t *avr, avr_cycle_count_t when, void *param) {
    harness_t *s = param;
    (void)avr;
    integrate(s, when);
    schedule_edge(s, when);
    /* simavr 1.6 copies every PORTD write onto the pin IRQs, so the firmware enabling its
       pull-ups (or writing another PORTD pin) overrides what the encoder drives: put the
       encoder's levels back. */
    uint16_t sp = s->avr->data[REG_SPL] | (s->avr->data[REG_SPH] << 8);
    if (sp < s->min_sp && sp > 0x100 && !stack_pointer_half_written(s->avr)) s->min_sp = sp;
    uint8_t pind = s->avr->data[REG_PIND];
    if (((pind >> ENC_A_PIN) & 1) != s->last_a) avr_raise_irq(s->enc_a, s->last_a);
    if (((pind >> ENC_B_PIN) & 1) != s->last_b) avr_raise_irq(s->enc_b, s->last_b);
    return when + s->substep;
}

/* ---- UART0 <-> pseudo-terminal, single-threaded and lossless ---------------------------
   (simavr's uart_pty part drops output when the host reads slowly and its thread can hang on
   exit, so the harness bridges the UART itself.) */
#define OUT_RING 65536
typedef struct bridge {
    int master, slave;
    char slave_name[128];
    uint8_t out[OUT_RING];      /* AVR -> host, not yet written to the pty */
    size_t out_read, out_write;
    uint8_t in[4096];           /* host -> AVR, not yet accepted by the UART */
    size_t in_len, in_pos;
    int xoff;
    avr_irq_t *uart_input;
    uint64_t overflows;
    int frame_ended;            /* the AVR sent a 0x00 (lock-step: the end of a frame) */
} bridge_t;

static size_t bridge_pending(const bridge_t *b) { return (b->out_write - b->out_read) & (OUT_RING - 1); }

static void bridge_feed(bridge_t *b) {
    while (!b->xoff && b->in_pos < b->in_len) avr_raise_irq(b->uart_input, b->in[b->in_pos++]);
}

static void on_uart_output(struct avr_irq_t *irq, uint32_t value, void *param) {
    bridge_t *b = param;
    (void)irq;
    if (bridge_pending(b) == OUT_RING - 1) { b->overflows++; return; }
    b->out[b->out_write] = (uint8_t)value;
    b->out_write = (b->out_write + 1) & (OUT_RING - 1);
    if ((uint8_t)value == 0) b->frame_ended = 1;
}

static void on_uart_xon(struct avr_irq_t *irq, uint32_t value, void *param) {
    bridge_t *b = param;
    (void)irq; (void)value;
    b->xoff = 0;
    bridge_feed(b);
}

static void on_uart_xoff(struct avr_irq_t *irq, uint32_t value, void *param) {
    bridge_t *b = param;
    (void)irq; (void)value;
    b->xoff = 1;
}

/* The AVR's UART0 wired to the bridge's queues (both modes). */
static void bridge_wire_uart(bridge_t *b, avr_t *avr) {
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);   /* binary; never usleep */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    b->uart_input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), on_uart_output, b);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), on_uart_xon, b);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), on_uart_xoff, b);
}

static int bridge_open(bridge_t *b, avr_t *avr) {
    memset(b, 0, sizeof(*b));
    b->xoff = 1;   /* until the UART says XON: bytes sent before the receiver is on are lost */
    if (openpty(&b->master, &b->slave, b->slave_name, NULL, NULL) < 0) return -1;
    struct termios tio;
    tcgetattr(b->slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(b->slave, TCSANOW, &tio);
    close(b->slave);   /* so that the master sees POLLHUP until the host opens the port */
    b->slave = -1;
    fcntl(b->master, F_SETFL, fcntl(b->master, F_GETFL) | O_NONBLOCK);
    bridge_wire_uart(b, avr);
    return 0;
}

/* Block until the host opens the pseudo-terminal (or a stop is requested). */
static void bridge_wait_for_host(bridge_t *b) {
    while (!should_stop()) {
        struct pollfd pfd = {b->master, POLLIN, 0};
        if (poll(&pfd, 1, 10) >= 0 && !(pfd.revents & POLLHUP)) return;
    }
}

/* Move bytes both ways without blocking. */
static void bridge_poll(bridge_t *b) {
    while (bridge_pending(b)) {
        size_t n = b->out_write >= b->out_read ? b->out_write - b->out_read : OUT_RING - b->out_read;
        ssize_t done = write(b->master, b->out + b->out_read, n);
        if (done <= 0) break;                               /* EAGAIN: the host is behind */
        b->out_read = (b->out_read + (size_t)done) & (OUT_RING - 1);
    }
    if (b->in_pos == b->in_len) {
        ssize_t got = read(b->master, b->in, sizeof(b->in));
        if (got > 0) { b->in_len = (size_t)got; b->in_pos = 0; }
    }
    bridge_feed(b);
}

static double wall_seconds(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void usage(const char *argv0) {
    fprintf(stderr,
            "usage: %s FIRMWARE.elf [--a A] [--b B] [--friction C] [--counts-per-rev N]\n"
            "          [--encoder-rate COUNTS_PER_S] [--driver dir-pwm|in1-in2] [--speed X]\n"
            "          [--substep-cycles N] [--boot-delay S] [--lockstep-fd FD]\n",
            argv0);
}

static double parse_number(const char *name, const char *text) {
    char *end;
    errno = 0;
    double v = strtod(text, &end);
    if (errno || end == text || *end || !isfinite(v)) {
        fprintf(stderr, "motorid-avr-sim: --%s must be a number, got '%s'\n", name, text);
        exit(2);
    }
    return v;
}

/* What the command line sets besides the motor (which goes straight into the harness). */
typedef struct options {
    const char *firmware;
    double speed_cap;     /* largest emulated / wall time ratio, 0 = free */
    double boot_delay;    /* s between the host opening the pty and the AVR starting */
    int lockstep_fd;      /* the host's socket in lock-step mode, -1 in real time */
} options_t;

/* Reads the command line into s and o; returns 0, or the exit status after a message. */
static int parse_options(int argc, char **argv, harness_t *s, options_t *o) {
    static const struct option options[] = {
        {"a", required_argument, 0, 'a'},          {"b", required_argument, 0, 'b'},
        {"friction", required_argument, 0, 'f'},   {"counts-per-rev", required_argument, 0, 'n'},
        {"encoder-rate", required_argument, 0, 'r'}, {"driver", required_argument, 0, 'd'},
        {"speed", required_argument, 0, 's'},      {"substep-cycles", required_argument, 0, 'c'},
        {"boot-delay", required_argument, 0, 'w'}, {"lockstep-fd", required_argument, 0, 'l'},
        {0, 0, 0, 0}};
    int opt;
    while ((opt = getopt_long(argc, argv, "", options, NULL)) != -1) {
        switch (opt) {
            case 'a': s->a = parse_number("a", optarg); break;
            case 'b': s->b = parse_number("b", optarg); break;
            case 'f': s->friction = parse_number("friction", optarg); break;
            case 'n': s->counts_per_rev = parse_number("counts-per-rev", optarg); break;
            case 'r': s->encoder_rate = parse_number("encoder-rate", optarg); break;
            case 's': o->speed_cap = parse_number("speed", optarg); break;
            case 'c': s->substep = (uint32_t)parse_number("substep-cycles", optarg); break;
            case 'w': o->boot_delay = parse_number("boot-delay", optarg); break;
            case 'l': o->lockstep_fd = (int)parse_number("lockstep-fd", optarg); break;
            case 'd':
                if (!strcmp(optarg, "dir-pwm")) s->driver = DRIVER_DIR_PWM;
                else if (!strcmp(optarg, "in1-in2")) s->driver = DRIVER_IN1_IN2;
                else {
                    fprintf(stderr, "motorid-avr-sim: --driver must be dir-pwm or in1-in2, got '%s'\n", optarg);
                    return 2;
                }
                break;
            default: usage(argv[0]); return 2;
        }
    }
    if (optind != argc - 1) { usage(argv[0]); return 2; }
    o->firmware = argv[optind];
    return 0;
}

/* Returns 0 when every setting is in range, else 2 after naming the first that is not. */
static int check_options(const harness_t *s, const options_t *o) {
    if (!(s->a > 0)) { fprintf(stderr, "motorid-avr-sim: --a must be > 0, got %g\n", s->a); return 2; }
    if (s->friction < 0) {
        fprintf(stderr, "motorid-avr-sim: --friction must be >= 0, got %g\n", s->friction); return 2;
    }
    if (!(s->counts_per_rev > 0)) {
        fprintf(stderr, "motorid-avr-sim: --counts-per-rev must be > 0, got %g\n", s->counts_per_rev); return 2;
    }
    if (s->substep < 1 || s->substep > 16000) {
        fprintf(stderr, "motorid-avr-sim: --substep-cycles must be 1...16000, got %u\n", s->substep); return 2;
    }
    if (o->boot_delay < 0 || o->boot_delay > 10) {
        fprintf(stderr, "motorid-avr-sim: --boot-delay must be 0...10 s, got %g\n", o->boot_delay); return 2;
    }
    if (o->lockstep_fd != -1 && (o->lockstep_fd < 0 || fcntl(o->lockstep_fd, F_GETFD) < 0)) {
        fprintf(stderr, "motorid-avr-sim: --lockstep-fd must be an open descriptor, got %d\n", o->lockstep_fd);
        return 2;
    }
    if (o->speed_cap < 0) {
        fprintf(stderr, "motorid-avr-sim: --speed must be >= 0, got %g\n", o->speed_cap); return 2;
    }
    return 0;
}

/* Loads the firmware into a fresh ATmega328P at 16 MHz and wires the encoder pins; 0 or 1. */
static int start_avr(harness_t *s, const char *firmware) {
    elf_firmware_t fw;
    memset(&fw, 0, sizeof(fw));
    if (elf_read_firmware(firmware, &fw) != 0) {
        fprintf(stderr, "motorid-avr-sim: cannot read firmware '%s'\n", firmware);
        return 1;
    }
    s->avr = avr_make_mcu_by_name("atmega328p");
    if (!s->avr) { fprintf(stderr, "motorid-avr-sim: simavr has no atmega328p\n"); return 1; }
    avr_init(s->avr);
    s->avr->frequency = 16000000;
    avr_load_firmware(s->avr, &fw);
    s->avr->log = LOG_ERROR;
    s->avr->data[REG_MCUSR] |= 1;   /* power-on reset */

    s->h = s->substep / (double)s->avr->frequency;
    s->e = exp(-s->a * s->h);
    s->one_minus_e_over_a = (1.0 - s->e) / s->a;
    s->h_minus_over_a = s->h - s->one_minus_e_over_a;
    watch_drive_registers(s);
    avr_register_io_write(s->avr, REG_PCIFR, on_pcifr_write, NULL);
    s->enc_a = avr_io_getirq(s->avr, AVR_IOCTL_IOPORT_GETIRQ('D'), ENC_A_PIN);
    s->enc_b = avr_io_getirq(s->avr, AVR_IOCTL_IOPORT_GETIRQ('D'), ENC_B_PIN);
    avr_raise_irq(s->enc_a, 0);
    avr_raise_irq(s->enc_b, 0);
    return 0;
}

/* The motor timer again after an AVR reset cleared simavr's cycle timers. */
static void keep_motor_timer(harness_t *s) {
    if (!avr_cycle_timer_status(s->avr, motor_step, s)) {
        s->resets++;
        avr_cycle_timer_register(s->avr, s->substep, motor_step, s);
    }
}

/* Every 4096 avr_run() calls: host flow control, the motor timer after a reset, the speed cap. */
static void housekeeping(harness_t *s, bridge_t *pty, double speed_cap, double wall0, avr_cycle_count_t cycle0) {
    /* Flow control towards the host: while more than 4 kB of the AVR's output wait for a
       busy host, the emulation pauses. Nothing is lost and the firmware's own (emulated)
       timing is untouched; a real USB-serial link has large host buffers instead. */
    bridge_poll(pty);
    while (!should_stop() && bridge_pending(pty) > 4096) {
        struct timespec ts = {0, 200000};
        nanosleep(&ts, NULL);
        s->flow_pauses++;
        bridge_poll(pty);
    }
    should_stop();                                          /* the parent may be gone */
    keep_motor_timer(s);                                    /* cleared by an AVR reset */
    if (speed_cap > 0) {
        double emulated = (s->avr->cycle - cycle0) / (double)s->avr->frequency;
        double ahead = emulated / speed_cap - (wall_seconds() - wall0);
        if (ahead > 0.002) {
            struct timespec ts = {0, (long)(ahead * 1e9)};
            nanosleep(&ts, NULL);
        }
    }
}

static void print_stats(harness_t *s, double wall0, avr_cycle_count_t cycle0, int state) {
    double wall = wall_seconds() - wall0;
    double emulated = (s->avr->cycle - cycle0) / (double)s->avr->frequency;
    printf("STATS emulated_s=%.6f wall_s=%.6f ratio=%.3f counts=%lld edges=%llu resets=%llu speed_rad_s=%.6f "
           "stack_bytes=%d flow_pauses=%llu unwatched_drive_changes=%llu state=%d\n",
           emulated, wall, wall > 0 ? emulated / wall : 0.0, (long long)s->emitted,
           (unsigned long long)s->edges, (unsigned long long)s->resets, s->speed, 0x8FF - s->min_sp,
           (unsigned long long)s->flow_pauses, (unsigned long long)s->unwatched_changes, state);
    fflush(stdout);
}

/* Runs the AVR until a signal stops it or it crashes; prints the STATS line; returns the state. */
static int run_emulation(harness_t *s, bridge_t *pty, double speed_cap) {
    avr_cycle_timer_register(s->avr, s->substep, motor_step, s);
    double wall0 = wall_seconds();
    avr_cycle_count_t cycle0 = s->avr->cycle;
    int state = cpu_Running;
    uint32_t n = 0;
    while (!stop_requested && state != cpu_Done && state != cpu_Crashed) {
        state = avr_run(s->avr);
        if (hang_requested && s->avr->sreg[S_I]) {   /* not inside an interrupt: simavr
                                                        ends a run on "rjmp ." with I clear */
            hang_requested = 0;
            hang_firmware(s->avr);
        }
        if (++n < 4096) continue;
        n = 0;
        housekeeping(s, pty, speed_cap, wall0, cycle0);
    }
    print_stats(s, wall0, cycle0, state);
    return state;
}

/* Reads exactly n bytes from the host's socket, polling so that a stop or the parent's death is
   seen; 0, or -1 when the host has closed it (or a stop was asked for). */
static int read_exactly(int fd, void *buffer, size_t n) {
    uint8_t *p = buffer;
    while (n > 0) {
        if (should_stop()) return -1;
        struct pollfd pfd = {fd, POLLIN, 0};
        if (poll(&pfd, 1, 100) <= 0) continue;
        ssize_t got = read(fd, p, n);
        if (got == 0) return -1;
        if (got < 0) { if (errno == EINTR || errno == EAGAIN) continue; return -1; }
        p += got;
        n -= (size_t)got;
    }
    return 0;
}

static int write_exactly(int fd, const void *buffer, size_t n) {
    const uint8_t *p = buffer;
    while (n > 0) {
        ssize_t done = write(fd, p, n);
        if (done < 0) { if (errno == EINTR || errno == EAGAIN) continue; return -1; }
        p += done;
        n -= (size_t)done;
    }
    return 0;
}

static uint64_t get_u64(const uint8_t *p) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = (v << 8) | p[i];
    return v;
}

static uint32_t get_u32(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24; }

static void put_u64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) { p[i] = (uint8_t)v; v >>= 8; } }

static void put_u32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) { p[i] = (uint8_t)v; v >>= 8; } }

#define LOCKSTEP_OUT_LIMIT (OUT_RING - 4096)   /* a grant stops early with this much output waiting */

/* Lock-step: emulated time moves only as the host grants it (the exchange is described at the
   top); returns the CPU state when the host goes away or a stop is asked for. */
static int run_lockstep(harness_t *s, bridge_t *b, int fd) {
    avr_cycle_timer_register(s->avr, s->substep, motor_step, s);
    double wall0 = wall_seconds();
    avr_cycle_count_t cycle0 = s->avr->cycle;
    int state = cpu_Running;
    static uint8_t reply[20 + OUT_RING];
    while (!should_stop()) {
        uint8_t header[20];
        if (read_exactly(fd, header, sizeof(header)) != 0) break;
        avr_cycle_count_t until = get_u64(header);
        int stop_on_frame = get_u32(header + 8) != 0;
        uint32_t id = get_u32(header + 12);
        uint32_t n = get_u32(header + 16);
        if (b->in_pos > 0) {                      /* keep what the UART has not taken, at the front */
            memmove(b->in, b->in + b->in_pos, b->in_len - b->in_pos);
            b->in_len -= b->in_pos;
            b->in_pos = 0;
        }
        if (n > sizeof(b->in) - b->in_len) {
            fprintf(stderr, "motorid-avr-sim: the host sent %u bytes, more than the %zu the UART's queue has left\n",
                    n, sizeof(b->in) - b->in_len);
            break;
        }
        if (n && read_exactly(fd, b->in + b->in_len, n) != 0) break;
        b->in_len += n;
        bridge_feed(b);
        b->frame_ended = 0;
        uint32_t steps = 0;
        while (!stop_requested && state != cpu_Done && state != cpu_Crashed && s->avr->cycle < until
               && !(stop_on_frame && b->frame_ended) && bridge_pending(b) < LOCKSTEP_OUT_LIMIT) {
            state = avr_run(s->avr);
            if (hang_requested && s->avr->sreg[S_I]) {
                hang_requested = 0;
                hang_firmware(s->avr);
            }
            if (++steps >= 4096) {
                steps = 0;
                keep_motor_timer(s);
                if (should_stop()) break;
            }
        }
        keep_motor_timer(s);
        size_t out = 0;
        while (bridge_pending(b)) {
            reply[20 + out++] = b->out[b->out_read];
            b->out_read = (b->out_read + 1) & (OUT_RING - 1);
        }
        put_u64(reply, s->avr->cycle);
        put_u32(reply + 8, (uint32_t)state);
        put_u32(reply + 12, id);
        put_u32(reply + 16, (uint32_t)out);
        if (write_exactly(fd, reply, 20 + out) != 0) break;
        if (state == cpu_Done || state == cpu_Crashed) break;
    }
    print_stats(s, wall0, cycle0, state);
    return state;
}

int main(int argc, char **argv) {
    parent_pid = getppid();
    harness_t s;
    memset(&s, 0, sizeof(s));
    s.a = 25.0;
    s.b = 3.0;
    s.counts_per_rev = 16667.0;
    s.substep = 16;
    s.min_sp = 0x8FF;
    options_t o = {NULL, 1.0, 0.05, -1};
    int status = parse_options(argc, argv, &s, &o);
    if (!status) status = check_options(&s, &o);
    if (!status) status = start_avr(&s, o.firmware);
    if (status) return status;

    static bridge_t pty;   /* static: 70 kB */
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGHUP, on_signal);
    signal(SIGUSR1, on_hang);
    signal(SIGPIPE, SIG_IGN);
    if (o.lockstep_fd >= 0) {
        memset(&pty, 0, sizeof(pty));
        pty.master = pty.slave = -1;
        pty.xoff = 1;
        bridge_wire_uart(&pty, s.avr);
        printf("LOCKSTEP\n");
        fflush(stdout);
        int state = run_lockstep(&s, &pty, o.lockstep_fd);
        _exit(state == cpu_Crashed ? 1 : 0);
    }
    if (bridge_open(&pty, s.avr) != 0) {
        fprintf(stderr, "motorid-avr-sim: cannot open a pseudo-terminal: %s\n", strerror(errno));
        return 1;
    }
    printf("PTY %s\n", pty.slave_name);
    fflush(stdout);

    /* A real Uno boots when the host opens the port (DTR reset) and then sits ~1 s in its
       bootloader; the emulated one starts when the host opens the pty, after --boot-delay
       (default 50 ms), so its BOOT frame cannot be flushed by the host's own open(). */
    bridge_wait_for_host(&pty);
    if (o.boot_delay > 0) {
        struct timespec ts = {(time_t)o.boot_delay, (long)((o.boot_delay - (time_t)o.boot_delay) * 1e9)};
        nanosleep(&ts, NULL);
    }
    int state = run_emulation(&s, &pty, o.speed_cap);
    bridge_poll(&pty);
    _exit(state == cpu_Crashed ? 1 : 0);
}
