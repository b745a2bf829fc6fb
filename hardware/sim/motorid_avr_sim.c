/*
 * motorid-avr-sim: run the bench firmware (an ATmega328P ELF) in simavr, with a simulated
 * DC motor and quadrature encoder wired to it and UART0 bridged to a pseudo-terminal.
 *
 *   motorid-avr-sim FIRMWARE.elf [--a 25] [--b 3] [--friction 0] [--counts-per-rev 16667]
 *                   [--encoder-rate COUNTS_PER_S] [--driver dir-pwm|in1-in2]
 *                   [--speed 1.0] [--substep-cycles 16]
 *
 * Prints "PTY <path>" on stdout once the pseudo-terminal exists, then runs until SIGTERM or
 * SIGINT, and prints one "STATS ..." line on stdout when it stops. SIGUSR1 hangs the firmware
 * (an endless loop with interrupts on) to test the AVR watchdog.
 *
 * The motor  d omega/dt = -a omega + b u - c sign(omega)  is integrated exactly (zero-order
 * hold) over sub-steps of --substep-cycles CPU cycles (default 16 = 1 us). The drive u is read
 * at each sub-step from the firmware's registers, because simavr 1.6 does not emulate the PWM
 * waveform on the pin: u = +-OCR2A (pin 11, Timer 2) with the sign from the DIR pin (8), or
 * from IN1/IN2 (8/9). A PWM pin that is not an output (during reset) reads as 0, as the
 * pull-down on the real board makes it. The encoder A/B inputs (pins 2/3) get one quadrature
 * edge per sub-step at most, when the shaft angle crosses a count boundary, so edges are spaced
 * as the motor turns them (to 1 us) up to 1 M counts/s.
 *
 * --encoder-rate R ignores the motor and turns the encoder at exactly R counts/s (4x counts):
 * that is how the firmware's encoder ceiling is measured.
 *
 * Time: simavr runs free, faster than real time on a desktop. The host times its HEARTBEATs on
 * the wall clock while the firmware's host-silence watchdog counts emulated time, so an
 * emulation running more than 4x faster than the wall clock would starve the watchdog. --speed
 * caps emulated time at that multiple of the wall clock (default 1.0: emulated time never runs
 * ahead of real time, so wall-clock heartbeats arrive at least as often as on a real board);
 * --speed 0 runs free.
 *
 * An AVR reset (the hardware watchdog, or a jump to 0) clears simavr's cycle timers: the main
 * loop checks every few thousand instructions that the motor timer is still registered and
 * registers it again if not.
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

#include <simavr/avr_ioport.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_irq.h>
#include <simavr/parts/uart_pty.h>

/* ATmega328P data-space addresses */
#define REG_PINB 0x23
#define REG_DDRB 0x24
#define REG_PORTB 0x25
#define REG_PIND 0x29
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

typedef struct harness {
    avr_t *avr;
    avr_irq_t *enc_a, *enc_b;
    enum driver driver;
    double a, b, friction, counts_per_rev, encoder_rate;
    uint32_t substep;
    /* exact ZOH coefficients over one sub-step, precomputed */
    double h, e, one_minus_e_over_a, h_minus_over_a;
    double speed;        /* rad/s */
    double position;     /* shaft angle in counts (4x) */
    int64_t emitted;     /* count the A/B pins currently show */
    int last_a, last_b;
    uint64_t edges;
    uint64_t resets;
    uint16_t min_sp;     /* lowest stack pointer seen (sampled every sub-step) */
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

/* Test hook (SIGUSR1): send the CPU into "rjmp ." at the top of the application flash with
   interrupts left on, as a firmware bug that hangs loop() would. Interrupts keep running; the
   AVR watchdog, no longer fed, resets the chip. */
#define HANG_ADDRESS 0x7000
static void hang_firmware(avr_t *avr) {
    avr->flash[HANG_ADDRESS] = 0xFF;       /* rjmp .-2 = 0xCFFF, little-endian */
    avr->flash[HANG_ADDRESS + 1] = 0xCF;
    avr->pc = HANG_ADDRESS;
}

static double drive(const harness_t *s) {
    const uint8_t *d = s->avr->data;
    if (!(d[REG_DDRB] & (1 << PWM_BIT))) return 0.0;          /* floating: pull-down */
    double magnitude;
    if (d[REG_TCCR2A] & (1 << BIT_COM2A1)) magnitude = d[REG_OCR2A];
    else magnitude = (d[REG_PORTB] & (1 << PWM_BIT)) ? 255.0 : 0.0;
    int dir = (d[REG_PORTB] >> DIR_BIT) & 1;
    if (s->driver == DRIVER_DIR_PWM) return dir ? magnitude : -magnitude;
    int in2 = (d[REG_PORTB] >> IN2_BIT) & 1;
    if (dir == in2) return 0.0;                               /* brake or coast */
    return dir ? magnitude : -magnitude;
}

static void set_encoder_pins(harness_t *s) {
    static const int A[4] = {0, 1, 1, 0}, B[4] = {0, 0, 1, 1};
    int q = (int)(s->emitted & 3);
    if (A[q] != s->last_a) { s->last_a = A[q]; avr_raise_irq(s->enc_a, A[q]); }
    if (B[q] != s->last_b) { s->last_b = B[q]; avr_raise_irq(s->enc_b, B[q]); }
}

static void integrate(harness_t *s) {
    const double to_counts = s->counts_per_rev / (2.0 * M_PI);
    if (s->encoder_rate != 0.0) {
        s->position += s->encoder_rate * s->h;
        return;
    }
    double u = drive(s);
    double force = s->b * u;
    double w = s->speed;
    if (s->friction > 0.0) {
        if (w == 0.0 && fabs(force) <= s->friction) return;   /* stuck */
        double sign = w != 0.0 ? (w > 0 ? 1.0 : -1.0) : (force > 0 ? 1.0 : -1.0);
        force -= s->friction * sign;
    }
    double target = force / s->a;                             /* steady state of this step */
    double w_next = s->e * w + target * (1.0 - s->e);
    double angle = s->one_minus_e_over_a * w + target * s->h_minus_over_a;
    if (s->friction > 0.0 && w != 0.0 && (w_next > 0) != (w > 0)) {
        /* speed crosses zero inside the sub-step: stop there (friction holds it if it can) */
        w_next = 0.0;
    }
    s->speed = w_next;
    s->position += angle * to_counts;
}

static avr_cycle_count_t motor_step(avr_t *avr, avr_cycle_count_t when, void *param) {
    harness_t *s = param;
    (void)avr;
    integrate(s);
    int64_t target = (int64_t)floor(s->position);
    if (target != s->emitted) {
        s->emitted += target > s->emitted ? 1 : -1;           /* one edge per sub-step */
        s->edges++;
        set_encoder_pins(s);
    }
    /* simavr 1.6 copies every PORTD write onto the pin IRQs, so the firmware enabling its
       pull-ups (or writing another PORTD pin) overrides what the encoder drives: put the
       encoder's levels back. */
    uint16_t sp = s->avr->data[REG_SPL] | (s->avr->data[REG_SPH] << 8);
    if (sp < s->min_sp && sp > 0x100) s->min_sp = sp;
    uint8_t pind = s->avr->data[REG_PIND];
    if (((pind >> ENC_A_PIN) & 1) != s->last_a) avr_raise_irq(s->enc_a, s->last_a);
    if (((pind >> ENC_B_PIN) & 1) != s->last_b) avr_raise_irq(s->enc_b, s->last_b);
    return when + s->substep;
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
            "          [--substep-cycles N]\n",
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

int main(int argc, char **argv) {
    harness_t s;
    memset(&s, 0, sizeof(s));
    s.a = 25.0;
    s.b = 3.0;
    s.counts_per_rev = 16667.0;
    s.substep = 16;
    s.min_sp = 0x8FF;
    double speed_cap = 1.0;
    static const struct option options[] = {
        {"a", required_argument, 0, 'a'},          {"b", required_argument, 0, 'b'},
        {"friction", required_argument, 0, 'f'},   {"counts-per-rev", required_argument, 0, 'n'},
        {"encoder-rate", required_argument, 0, 'r'}, {"driver", required_argument, 0, 'd'},
        {"speed", required_argument, 0, 's'},      {"substep-cycles", required_argument, 0, 'c'},
        {0, 0, 0, 0}};
    int opt;
    while ((opt = getopt_long(argc, argv, "", options, NULL)) != -1) {
        switch (opt) {
            case 'a': s.a = parse_number("a", optarg); break;
            case 'b': s.b = parse_number("b", optarg); break;
            case 'f': s.friction = parse_number("friction", optarg); break;
            case 'n': s.counts_per_rev = parse_number("counts-per-rev", optarg); break;
            case 'r': s.encoder_rate = parse_number("encoder-rate", optarg); break;
            case 's': speed_cap = parse_number("speed", optarg); break;
            case 'c': s.substep = (uint32_t)parse_number("substep-cycles", optarg); break;
            case 'd':
                if (!strcmp(optarg, "dir-pwm")) s.driver = DRIVER_DIR_PWM;
                else if (!strcmp(optarg, "in1-in2")) s.driver = DRIVER_IN1_IN2;
                else {
                    fprintf(stderr, "motorid-avr-sim: --driver must be dir-pwm or in1-in2, got '%s'\n", optarg);
                    return 2;
                }
                break;
            default: usage(argv[0]); return 2;
        }
    }
    if (optind != argc - 1) { usage(argv[0]); return 2; }
    if (!(s.a > 0)) { fprintf(stderr, "motorid-avr-sim: --a must be > 0, got %g\n", s.a); return 2; }
    if (s.friction < 0) { fprintf(stderr, "motorid-avr-sim: --friction must be >= 0, got %g\n", s.friction); return 2; }
    if (!(s.counts_per_rev > 0)) { fprintf(stderr, "motorid-avr-sim: --counts-per-rev must be > 0, got %g\n", s.counts_per_rev); return 2; }
    if (s.substep < 1 || s.substep > 16000) { fprintf(stderr, "motorid-avr-sim: --substep-cycles must be 1...16000, got %u\n", s.substep); return 2; }
    if (speed_cap < 0) { fprintf(stderr, "motorid-avr-sim: --speed must be >= 0, got %g\n", speed_cap); return 2; }

    elf_firmware_t fw;
    memset(&fw, 0, sizeof(fw));
    if (elf_read_firmware(argv[optind], &fw) != 0) {
        fprintf(stderr, "motorid-avr-sim: cannot read firmware '%s'\n", argv[optind]);
        return 1;
    }
    s.avr = avr_make_mcu_by_name("atmega328p");
    if (!s.avr) { fprintf(stderr, "motorid-avr-sim: simavr has no atmega328p\n"); return 1; }
    avr_init(s.avr);
    s.avr->frequency = 16000000;
    avr_load_firmware(s.avr, &fw);
    s.avr->log = LOG_ERROR;
    s.avr->data[REG_MCUSR] |= 1;   /* power-on reset */

    s.h = s.substep / (double)s.avr->frequency;
    s.e = exp(-s.a * s.h);
    s.one_minus_e_over_a = (1.0 - s.e) / s.a;
    s.h_minus_over_a = s.h - s.one_minus_e_over_a;
    s.enc_a = avr_io_getirq(s.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), ENC_A_PIN);
    s.enc_b = avr_io_getirq(s.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), ENC_B_PIN);
    avr_raise_irq(s.enc_a, 0);
    avr_raise_irq(s.enc_b, 0);

    uart_pty_t pty;
    memset(&pty, 0, sizeof(pty));
    uart_pty_init(s.avr, &pty);
    uart_pty_connect(&pty, '0');
    printf("PTY %s\n", pty.pty.slavename);
    fflush(stdout);

    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGHUP, on_signal);
    signal(SIGUSR1, on_hang);

    avr_cycle_timer_register(s.avr, s.substep, motor_step, &s);
    double wall0 = wall_seconds();
    avr_cycle_count_t cycle0 = s.avr->cycle;
    int state = cpu_Running;
    uint32_t n = 0;
    while (!stop_requested && state != cpu_Done && state != cpu_Crashed) {
        state = avr_run(s.avr);
        if (hang_requested && s.avr->sreg[S_I]) {   /* not inside an interrupt: simavr
                                                        ends a run on "rjmp ." with I clear */
            hang_requested = 0;
            hang_firmware(s.avr);
        }
        if (++n < 4096) continue;
        n = 0;
        if (!avr_cycle_timer_status(s.avr, motor_step, &s)) {   /* cleared by an AVR reset */
            s.resets++;
            avr_cycle_timer_register(s.avr, s.substep, motor_step, &s);
        }
        if (speed_cap > 0) {
            double emulated = (s.avr->cycle - cycle0) / (double)s.avr->frequency;
            double ahead = emulated / speed_cap - (wall_seconds() - wall0);
            if (ahead > 0.002) {
                struct timespec ts = {0, (long)(ahead * 1e9)};
                nanosleep(&ts, NULL);
            }
        }
    }
    double wall = wall_seconds() - wall0;
    double emulated = (s.avr->cycle - cycle0) / (double)s.avr->frequency;
    printf("STATS emulated_s=%.6f wall_s=%.6f ratio=%.3f counts=%lld edges=%llu resets=%llu speed_rad_s=%.6f "
           "stack_bytes=%d state=%d\n",
           emulated, wall, wall > 0 ? emulated / wall : 0.0, (long long)s.emitted,
           (unsigned long long)s.edges, (unsigned long long)s.resets, s.speed, 0x8FF - s.min_sp, state);
    fflush(stdout);
    /* Not uart_pty_stop(): in simavr 1.6 it can wait forever for its thread (seen about one
       time in six). Exiting closes the pty and ends the thread. */
    _exit(state == cpu_Crashed ? 1 : 0);
}
