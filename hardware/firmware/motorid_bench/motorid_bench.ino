// motorid bench firmware for an Arduino Uno (ATmega328P, 16 MHz).
//
// Implements hardware/PROTOCOL.md (protocol version 6) exactly: COBS frames with CRC-16,
// CONFIG/WAVE/CONTROL/REFERENCE/START/STOP/HEARTBEAT from the host, SAMPLE/END/FAULT back.
// In closed loop (a CONTROL naming a controller) each tick computes its duty from the counts
// it has just read with the controller's integer step (motorsim/fixed_point.py is the reference).
//
// Timing: Timer 1 (CTC, /8) is the sample clock. At each tick its interrupt applies the duty
// latched at the previous tick and snapshots the encoder count and micros() at the tick's
// instant, 40 us after the compare to 3 cycles whenever the interrupt started (the pins read and
// the duty written by adjacent instructions, so the two are one instant), computes this sample's
// duty (the waveform's or the controller's, with interrupts re-enabled: the encoder may preempt it),
// queues the SAMPLE and latches the duty for the next tick: an exact zero-order hold with a
// one-sample delay, the same in open and closed loop.
// loop() only parses received bytes and sends at most one frame per pass.
// The encoder is decoded by a pin-change interrupt that reads the port register directly.
// Wiring, flashing and measured figures: hardware/firmware/README.md.

#include <Arduino.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <avr/wdt.h>
#include <util/crc16.h>

#include "config.h"
#include "sine_table.h"

// ---------------------------------------------------------------------------------------------
// Protocol constants (hardware/PROTOCOL.md)
#define PROTOCOL_VERSION 6
#define FIRMWARE_VERSION 0x0502  // major << 8 | minor: 5.2
#define MAX_PAYLOAD 60
#define MAX_BODY (MAX_PAYLOAD + 4)
#define MAX_ENCODED (MAX_BODY + 2)

#define T_HELLO 0x01
#define T_CONFIG 0x02
#define T_WAVE 0x03
#define T_START 0x04
#define T_STOP 0x05
#define T_HEARTBEAT 0x06
#define T_CONTROL 0x07
#define T_REFERENCE 0x08
#define T_HELLO_ACK 0x81
#define T_ACK 0x82
#define T_NAK 0x83
#define T_SAMPLE 0x84
#define T_END 0x85
#define T_FAULT 0x86
#define T_BOOT 0x87

#define NAK_BUSY 1
#define NAK_BAD_LENGTH 2
#define NAK_BAD_VALUE 3
#define NAK_NOT_CONFIGURED 4
#define NAK_UNKNOWN_TYPE 5

#define END_COMPLETE 0
#define END_STOPPED 1
#define END_WATCHDOG 2
#define END_FAULT 3

#define FAULT_HOST_SILENCE 1
#define FAULT_QUEUE_OVERFLOW 2
#define FAULT_ENCODER 3

#define WAVE_CONSTANT 0
#define WAVE_STEP 1
#define WAVE_MULTISINE 2
#define WAVE_CHIRP 3
#define WAVE_PRBS 4
#define WAVE_ODD_MULTISINE 5
#define MAX_COMPONENTS 4
#define MAX_ODD_LINES 64          // odd harmonics of an odd multisine, excited or left out
#define LFSR16_MASK 0xB400
#define MAX_LEVEL 1023

#define CTRL_NONE 0
#define CTRL_MPC 1
#define CTRL_PI 2
#define CTRL_POSITION 3
#define CTRL_FEEDFORWARD 4
#define CTRL_LQR 5
#define CTRL_LQR_POSITION 6
#define CTRL_LQR_INTEGRAL 7
#define MAX_GAINS 14
#define REF_CONSTANT 0
#define REF_STEP 1
#define REF_MULTISINE 2
#define REF_TRAPEZOID 3
#define MAX_REFERENCE 65535L
#define GAIN_BITS 16
#define SPEED_REFERENCE_SCALE 16   // 2^SPEED_REFERENCE_BITS: speed references in 1/16 count per sample

#define FLAG_ENCODER_ERROR 0x01
#define FLAG_LATE 0x02

// ---------------------------------------------------------------------------------------------
// Pin mapping resolved at compile time (register-level I/O in the interrupts)
#if PIN_ENC_A <= 7
#define ENC_PCINT_vect PCINT2_vect
#define ENC_PIN_REG PIND
#define ENC_PCMSK PCMSK2
#define ENC_PCIE PCIE2
#define ENC_A_BIT (PIN_ENC_A)
#elif PIN_ENC_A <= 13
#define ENC_PCINT_vect PCINT0_vect
#define ENC_PIN_REG PINB
#define ENC_PCMSK PCMSK0
#define ENC_PCIE PCIE0
#define ENC_A_BIT (PIN_ENC_A - 8)
#elif PIN_ENC_A <= 19
#define ENC_PCINT_vect PCINT1_vect
#define ENC_PIN_REG PINC
#define ENC_PCMSK PCMSK1
#define ENC_PCIE PCIE1
#define ENC_A_BIT (PIN_ENC_A - 14)
#else
#error "PIN_ENC_A must be 0..19"
#endif
#if (PIN_ENC_A <= 7) != (PIN_ENC_B <= 7) || (PIN_ENC_A >= 14) != (PIN_ENC_B >= 14)
#error "PIN_ENC_A and PIN_ENC_B must be on the same port (0-7, 8-13 or 14-19)"
#endif
#define ENC_B_BIT (PIN_ENC_B <= 7 ? PIN_ENC_B : PIN_ENC_B <= 13 ? PIN_ENC_B - 8 : PIN_ENC_B - 14)
#define ENC_A_MASK (1 << ENC_A_BIT)
#define ENC_B_MASK (1 << ENC_B_BIT)

#if PIN_PWM == 11
#define PWM_OCR OCR2A
#define PWM_COM_BITS _BV(COM2A1)
#elif PIN_PWM == 3
#define PWM_OCR OCR2B
#define PWM_COM_BITS _BV(COM2B1)
#else
#error "PIN_PWM must be 11 (OC2A) or 3 (OC2B): Timer 2 drives the PWM"
#endif
#if PIN_PWM == PIN_ENC_A || PIN_PWM == PIN_ENC_B
#error "PIN_PWM must not be an encoder pin"
#endif

#if PWM_PRESCALER == 1
#define PWM_CS_BITS _BV(CS20)
#elif PWM_PRESCALER == 8
#define PWM_CS_BITS _BV(CS21)
#elif PWM_PRESCALER == 64
#define PWM_CS_BITS _BV(CS22)
#else
#error "PWM_PRESCALER must be 1, 8 or 64"
#endif

#if DRIVER_TYPE != DRIVER_DIR_PWM && DRIVER_TYPE != DRIVER_IN1_IN2
#error "DRIVER_TYPE must be DRIVER_DIR_PWM or DRIVER_IN1_IN2"
#endif

// ---------------------------------------------------------------------------------------------
// Reset cause: MCUSR read before anything clears it. Optiboot clears MCUSR itself and passes
// its old value in r2, so r2 is the fallback when MCUSR reads 0.
uint8_t boot_mcusr __attribute__((section(".noinit")));
uint8_t boot_r2 __attribute__((section(".noinit")));
uint8_t reset_cause;  // set in setup()
void capture_reset_cause(void) __attribute__((naked, used, section(".init3")));
void capture_reset_cause(void) {
  __asm__ __volatile__("sts boot_r2, r2");
  boot_mcusr = MCUSR;
  MCUSR = 0;
  wdt_disable();  // after a watchdog reset the watchdog stays armed at 15 ms
}

// ---------------------------------------------------------------------------------------------
// Types

struct Sample {
  uint32_t index;
  uint32_t time_us;
  int32_t counts;
  int16_t duty;
  uint8_t flags;
};

struct Config {
  uint32_t sample_period_us;
  uint32_t n_samples;
  int16_t duty_limit;
  uint8_t decoding;
  uint16_t watchdog_ms;
};

struct Component {
  int16_t amplitude;
  uint32_t phase0;
  uint32_t phase_inc;
};

struct Wave {
  uint8_t kind;
  int16_t level_a;      // CONSTANT level, STEP before, MULTISINE/CHIRP offset, PRBS low
  int16_t level_b;      // STEP after, CHIRP amplitude, PRBS high
  uint32_t word_a;      // STEP step_index, CHIRP phase0
  uint32_t word_b;      // CHIRP inc0
  int32_t word_c;       // CHIRP inc_step
  uint8_t n;            // MULTISINE components, PRBS order, ODD_MULTISINE period_log2
  uint16_t seed;        // PRBS, ODD_MULTISINE
  uint16_t hold;        // PRBS
  uint8_t max_harmonic; // ODD_MULTISINE
  uint8_t group;        // ODD_MULTISINE
  Component comp[MAX_COMPONENTS];
};

// Running state of the waveform generator (reset at START).
struct WaveState {
  uint32_t k;
  uint32_t phase[MAX_COMPONENTS];
  uint32_t inc;
  uint16_t lfsr;
  uint16_t hold_left;
  uint8_t bit;
};

// CONTROL: the controller and its Q16 gains in wire order (PROTOCOL.md "Closed loop").
struct Control {
  uint8_t kind;
  uint8_t preview;
  uint8_t n;
  int32_t gains[MAX_GAINS];
};

struct RefComponent {
  int32_t amplitude;
  uint32_t phase0;
  uint32_t phase_inc;
};

// REFERENCE: the integer reference the controller tracks.
struct Reference {
  uint8_t kind;
  int32_t level;        // CONSTANT level, STEP after, MULTISINE offset, TRAPEZOID plateau
  int32_t before;       // STEP
  uint32_t start;       // STEP switch, TRAPEZOID first sample
  uint32_t ramp;        // TRAPEZOID
  uint32_t hold;        // TRAPEZOID
  uint8_t n;            // MULTISINE
  RefComponent comp[MAX_COMPONENTS];
};

// Running state of the controller (reset at START; only the Timer 1 ISR touches it then).
struct ControlState {
  int32_t previous;
  int32_t origin;
  int64_t integral;
  int16_t history[MAX_GAINS];
  uint8_t n_history;
};

struct Response {
  uint8_t type;       // T_ACK, T_NAK or T_HELLO_ACK
  uint8_t ref_type;
  uint8_t ref_frame_seq;
  uint8_t reason;
};

#define RESPONSE_QUEUE_LEN 8

// ---------------------------------------------------------------------------------------------
// State shared with interrupts (volatile) and loop-only state.

// Encoder (pin-change ISR)
volatile int32_t enc_count = 0;
volatile uint32_t enc_errors = 0;
volatile uint8_t enc_previous = 0;   // last (A << 1 | B), shifted left by 2
volatile uint8_t enc_decoding = 4;
// Decoding tables indexed by (previous << 2 | current), current = A << 1 | B: +1/-1 count,
// 0 nothing, 2 an illegal transition. x4: every edge of A and B; both changing at once is
// illegal. x2 and x1 interrupt on A only: A must have changed (else an edge pair was missed);
// x2 counts both A edges, x1 only rising ones; B gives the direction.
#define ILLEGAL 2
const int8_t DECODE_X4[16] PROGMEM = {0, -1, +1, ILLEGAL, +1, 0, ILLEGAL, -1,
                                      -1, ILLEGAL, 0, +1, ILLEGAL, +1, -1, 0};
const int8_t DECODE_X2[16] PROGMEM = {ILLEGAL, ILLEGAL, +1, -1, ILLEGAL, ILLEGAL, +1, -1,
                                      -1, +1, ILLEGAL, ILLEGAL, -1, +1, ILLEGAL, ILLEGAL};
const int8_t DECODE_X1[16] PROGMEM = {ILLEGAL, ILLEGAL, +1, -1, ILLEGAL, ILLEGAL, +1, -1,
                                      0, 0, ILLEGAL, ILLEGAL, 0, 0, ILLEGAL, ILLEGAL};
int8_t decode_table[16];             // the active table, in RAM for a fast lookup

// Sample clock (Timer 1 ISR)
volatile uint8_t running = 0;
volatile uint32_t tick_index = 0;
// The duty latched for the next tick, split as the tick writes it: the PWM compare value and the
// direction level (see latch_duty, apply_latched).
volatile uint8_t next_magnitude = 0;
volatile uint8_t next_level = DIR_FORWARD_LEVEL;
volatile uint8_t tick_late = 0;
volatile uint16_t tick_overruns = 0;
volatile uint32_t samples_dropped = 0;
volatile uint32_t errors_at_last_sample = 0;
volatile uint32_t errors_at_start = 0;
volatile uint32_t errors_at_stop = 0;
volatile uint8_t fault_code = 0;      // pending FAULT frame (0: none)
volatile uint32_t fault_index = 0;
volatile uint8_t end_pending = 0;
volatile uint8_t end_reason = 0;
volatile uint8_t overflow_reported = 0;
uint16_t sub_len_q = 0;               // sample period split into sub-intervals of Timer 1
uint8_t sub_count = 1, sub_long = 0, sub_pos = 0;

// Sample queue: written by the Timer 1 ISR, read by loop().
Sample queue[SAMPLE_QUEUE_LEN];
volatile uint8_t queue_head = 0;      // next slot to write (ISR)
volatile uint8_t queue_tail = 0;      // next slot to read (loop)

// Experiment
Config cfg;
Wave wave;
WaveState ws;
// ODD_MULTISINE: the excited harmonics and their running phases (set up at START)
uint8_t odd_harmonic[MAX_ODD_LINES];
union OddPhase {   // a line's u32 phase; its steps change only the high half (little-endian: half[1])
  uint32_t word;
  uint16_t half[2];
};
OddPhase odd_phase[MAX_ODD_LINES];
uint8_t odd_lines;
uint8_t have_config = 0, have_wave = 0, have_reference = 0;
Control control;
Reference reference;
ControlState cs;

// Link (loop only)
uint8_t rx_buf[MAX_ENCODED];
uint8_t rx_len = 0;
uint8_t rx_discarding = 0;
uint16_t rx_errors = 0;
uint8_t tx_frame_seq = 0;
uint32_t samples_sent = 0;
uint32_t last_rx_ms = 0;
uint8_t boot_pending = 1;
Response responses[RESPONSE_QUEUE_LEN];
uint8_t resp_head = 0, resp_tail = 0;

volatile uint8_t *dir_port;           // direction output(s), resolved once in setup()
uint8_t dir_mask;
#if DRIVER_TYPE == DRIVER_IN1_IN2
volatile uint8_t *in2_port;
uint8_t in2_mask;
#endif

// ---------------------------------------------------------------------------------------------
// Little-endian helpers

static uint16_t get_u16(const uint8_t *p) { return (uint16_t)p[0] | ((uint16_t)p[1] << 8); }
static uint32_t get_u32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static uint8_t *put_u16(uint8_t *p, uint16_t v) { p[0] = v; p[1] = v >> 8; return p + 2; }
static uint8_t *put_u32(uint8_t *p, uint32_t v) {
  p[0] = v; p[1] = v >> 8; p[2] = v >> 16; p[3] = v >> 24; return p + 4;
}

// ---------------------------------------------------------------------------------------------
// H-bridge

// Apply a signed duty (|duty| <= 255). Interrupts must be off (ISR or cli()).
static inline void apply_duty(int16_t duty) {
  uint8_t forward = duty >= 0;
  uint8_t magnitude = forward ? duty : -duty;
  uint8_t level = forward ? DIR_FORWARD_LEVEL : !DIR_FORWARD_LEVEL;
  if (level) *dir_port |= dir_mask; else *dir_port &= ~dir_mask;
#if DRIVER_TYPE == DRIVER_IN1_IN2
  if (level) *in2_port &= ~in2_mask; else *in2_port |= in2_mask;
#endif
  PWM_OCR = magnitude;
}

// Latch a signed duty (|duty| <= 255) for the next tick. Interrupts must be off.
static inline void latch_duty(int16_t duty) {
  next_magnitude = duty >= 0 ? duty : -duty;
  next_level = duty >= 0 ? DIR_FORWARD_LEVEL : !DIR_FORWARD_LEVEL;
}

// The direction port's value with the latched duty's direction (the tick writes it, and the
// magnitude, at its instant; see the Timer 1 ISR). Interrupts must be off.
static inline uint8_t latched_direction_port(void) __attribute__((always_inline));
static inline uint8_t latched_direction_port(void) {
  uint8_t port = *dir_port;
  return next_level ? port | dir_mask : port & ~dir_mask;
}

#if DRIVER_TYPE == DRIVER_IN1_IN2
// IN2, the other direction pin, to the latched duty's direction. Interrupts must be off.
static inline void apply_latched_in2(void) __attribute__((always_inline));
static inline void apply_latched_in2(void) {
  if (next_level) *in2_port &= ~in2_mask; else *in2_port |= in2_mask;
}
#endif

static void setup_bridge(void) {
  PWM_OCR = 0;
  pinMode(PIN_PWM, OUTPUT);
#if DRIVER_TYPE == DRIVER_DIR_PWM
  pinMode(PIN_DIR, OUTPUT);
  dir_port = portOutputRegister(digitalPinToPort(PIN_DIR));
  dir_mask = digitalPinToBitMask(PIN_DIR);
#else
  pinMode(PIN_IN1, OUTPUT);
  pinMode(PIN_IN2, OUTPUT);
  dir_port = portOutputRegister(digitalPinToPort(PIN_IN1));
  dir_mask = digitalPinToBitMask(PIN_IN1);
  in2_port = portOutputRegister(digitalPinToPort(PIN_IN2));
  in2_mask = digitalPinToBitMask(PIN_IN2);
#endif
  // Timer 2: phase-correct 8-bit PWM; OCR = 0 is a steady low, OCR = 255 a steady high.
  TCCR2A = PWM_COM_BITS | _BV(WGM20);
  TCCR2B = PWM_CS_BITS;
  cli();
  apply_duty(0);
  sei();
}

// ---------------------------------------------------------------------------------------------
// Encoder: pin-change interrupt, register-level.

// The encoder's (A << 1 | B) from a read of its port.
static inline uint8_t encoder_bits(uint8_t pins) __attribute__((always_inline));
static inline uint8_t encoder_bits(uint8_t pins) {
  uint8_t now = 0;
  if (pins & ENC_A_MASK) now |= 2;
  if (pins & ENC_B_MASK) now |= 1;
  return now;
}

static inline uint8_t encoder_pins(void) __attribute__((always_inline));
static inline uint8_t encoder_pins(void) { return encoder_bits(ENC_PIN_REG); }

// Count the transition from the pins last seen to `now`. Interrupts must be off (this ISR, or the
// tick's instant, which counts an edge whose interrupt has not run yet).
static inline void encoder_step(uint8_t now) __attribute__((always_inline));
static inline void encoder_step(uint8_t now) {
  int8_t d = decode_table[enc_previous | now];
  enc_previous = now << 2;
  if (d == 0) return;
  if (d == ILLEGAL) {
    enc_errors++;
    return;
  }
  if (d > 0) enc_count++;
  else enc_count--;
}

ISR(ENC_PCINT_vect) {
  encoder_step(encoder_pins());
}

// Select the decoding table and the pins that interrupt (x4: A and B; x2, x1: A only).
static void setup_encoder(uint8_t decoding) {
  const int8_t *table = decoding == 4 ? DECODE_X4 : decoding == 2 ? DECODE_X2 : DECODE_X1;
  uint8_t sreg = SREG;
  cli();
  for (uint8_t i = 0; i < 16; i++) decode_table[i] = pgm_read_byte(&table[i]);
  enc_decoding = decoding;
  ENC_PCMSK = decoding == 4 ? (ENC_A_MASK | ENC_B_MASK) : ENC_A_MASK;
  PCIFR = _BV(ENC_PCIE);               // clear first: an edge after the read below interrupts
  enc_previous = encoder_pins() << 2;
  PCICR |= _BV(ENC_PCIE);
  SREG = sreg;
}

// ---------------------------------------------------------------------------------------------
// Waveform generator (PROTOCOL.md "Waveforms"; motorsim/excitation.py is the reference).

static int16_t sine_q15(uint32_t phase) {
  uint16_t i = phase >> 22;
  uint16_t f = (phase >> 6) & 0xFFFF;
  int16_t y0 = pgm_read_word(&SINE_TABLE[i]);
  int16_t y1 = pgm_read_word(&SINE_TABLE[(i + 1) & (SINE_TABLE_SIZE - 1)]);
  return y0 + (int16_t)(((int32_t)(y1 - y0) * (int32_t)f) >> 16);
}

static const uint16_t PRBS_MASK[17] PROGMEM = {
    0, 0, 0x3, 0x6, 0xC, 0x14, 0x30, 0x60, 0xB8, 0x110, 0x240, 0x500, 0xE08, 0x1C80,
    0x3802, 0x6000, 0xB400};

// The next 16-bit word of the order-16 Galois LFSR (PRBS arithmetic), least significant bit first.
static uint16_t lfsr16_word(uint16_t *state) {
  uint16_t word = 0;
  for (uint8_t b = 0; b < 16; b++) {
    uint16_t out = *state & 1;
    *state >>= 1;
    if (out) *state ^= LFSR16_MASK;
    word |= out << b;
  }
  return word;
}

// ODD_MULTISINE lines and start phases (PROTOCOL.md "Waveforms", motorsim.excitation.OddMultisine).
static void odd_multisine_setup(void) {
  uint8_t n_odd = (wave.max_harmonic + 1) / 2;
  uint8_t left_out[MAX_ODD_LINES / 8];  // a bit per odd line
  memset(left_out, 0, sizeof(left_out));
  if (wave.group) {
    uint16_t state = 1;  // left-out lines: the LFSR from 1, one word per group of odd lines from 3
    for (uint8_t first = 1; first < n_odd; first += wave.group) {
      uint8_t pick = lfsr16_word(&state) % wave.group;
      uint8_t i = first + pick;
      if (first + wave.group <= n_odd) left_out[i >> 3] |= 1 << (i & 7);
    }
  }
  uint16_t state = wave.seed;
  odd_lines = 0;
  for (uint8_t i = 0; i < n_odd; i++) {
    uint16_t word = wave.seed ? lfsr16_word(&state) : 0;
    if (left_out[i >> 3] & (1 << (i & 7))) continue;
    odd_harmonic[odd_lines] = 2 * i + 1;
    odd_phase[odd_lines].word = (uint32_t)word << 16;
    odd_lines++;
  }
  if (wave.seed == 0) {  // Schroeder: -ceil(j (j - 1) 2^31 / F) mod 2^32 for the j-th of F lines
    for (uint8_t j = 1; j <= odd_lines; j++) {
      uint64_t x = ((uint64_t)((uint16_t)j * (j - 1))) << 31;
      odd_phase[j - 1].word = (uint32_t)0 - (uint32_t)((x + odd_lines - 1) / odd_lines);
    }
  }
}

static void wave_reset(void) {
  ws.k = 0;
  for (uint8_t j = 0; j < MAX_COMPONENTS; j++) ws.phase[j] = wave.comp[j].phase0;
  ws.phase[0] = wave.kind == WAVE_CHIRP ? wave.word_a : ws.phase[0];
  ws.inc = wave.word_b;
  ws.lfsr = wave.seed;
  ws.hold_left = 0;
  ws.bit = 0;
  if (wave.kind == WAVE_ODD_MULTISINE) odd_multisine_setup();
}

// Duty for sample ws.k (before clamping), then advance to ws.k + 1.
static int32_t wave_next(void) {
  int32_t duty;
  switch (wave.kind) {
    case WAVE_STEP:
      duty = ws.k < wave.word_a ? wave.level_a : wave.level_b;
      break;
    case WAVE_MULTISINE: {
      int32_t acc = 0;
      for (uint8_t j = 0; j < wave.n; j++) {
        acc += (int32_t)wave.comp[j].amplitude * sine_q15(ws.phase[j]);
        ws.phase[j] += wave.comp[j].phase_inc;
      }
      duty = wave.level_a + ((acc + 16384) >> 15);
      break;
    }
    case WAVE_CHIRP:
      duty = wave.level_a + (((int32_t)wave.level_b * sine_q15(ws.phase[0]) + 16384) >> 15);
      ws.phase[0] += ws.inc;
      ws.inc += (uint32_t)wave.word_c;
      break;
    case WAVE_PRBS:
      if (ws.hold_left == 0) {
        uint8_t out = ws.lfsr & 1;
        ws.lfsr >>= 1;
        if (out) ws.lfsr ^= pgm_read_word(&PRBS_MASK[wave.n]);
        ws.bit = out;
        ws.hold_left = wave.hold;
      }
      ws.hold_left--;
      duty = ws.bit ? wave.level_b : wave.level_a;
      break;
    case WAVE_ODD_MULTISINE: {  // amplitude x sum, as exact as the sum of products: no overflow at 64 lines
      int32_t sum = 0;
      uint16_t step = 1U << (16 - wave.n);  // a harmonic's phase step is h << (32 - n) = (h * step) << 16
      for (uint8_t j = 0; j < odd_lines; j++) {
        sum += sine_q15(odd_phase[j].word);
        odd_phase[j].half[1] += odd_harmonic[j] * step;   // h < 2^(n-1), so h * step < 2^15: no overflow
      }
      duty = wave.level_a + (((int32_t)wave.level_b * sum + 16384) >> 15);
      break;
    }
    default:  // WAVE_CONSTANT
      duty = wave.level_a;
      break;
  }
  ws.k++;
  if (duty > cfg.duty_limit) duty = cfg.duty_limit;
  if (duty < -cfg.duty_limit) duty = -cfg.duty_limit;
  return duty;
}

// ---------------------------------------------------------------------------------------------
// Closed loop (PROTOCOL.md "Closed loop"; motorsim/fixed_point.py ControlLoop is the reference).

// floor(a / b) for b > 0 (C's division truncates towards zero).
static int32_t floor_div(int64_t a, uint32_t b) {
  int64_t q = a / (int64_t)b;
  if (a < 0 && q * (int64_t)b != a) q--;
  return (int32_t)q;
}

// The reference at sample j, from its integer words.
static int32_t reference_at(uint32_t j) {
  switch (reference.kind) {
    case REF_STEP:
      return j < reference.start ? reference.before : reference.level;
    case REF_MULTISINE: {
      int32_t acc = 0;  // sum |amplitude| <= 65535, so |acc| < 65535 * 32768 < 2^31
      for (uint8_t c = 0; c < reference.n; c++) {
        const RefComponent *k = &reference.comp[c];
        acc += k->amplitude * (int32_t)sine_q15(k->phase0 + j * k->phase_inc);
      }
      return reference.level + ((acc + 16384) >> 15);
    }
    case REF_TRAPEZOID: {
      int32_t i = (int32_t)j - (int32_t)reference.start;
      int32_t nr = (int32_t)reference.ramp, nh = (int32_t)reference.hold;
      int32_t m = i < nr + nh ? i : 2 * nr + nh - i;
      if (m < 0) m = 0;
      if (m > nr) m = nr;
      if (nr <= 32767) {  // |level * m| < 65536 * 32768: 32-bit arithmetic suffices
        int32_t a = reference.level * m;
        int32_t q = a / nr;
        return (a < 0 && q * nr != a) ? q - 1 : q;
      }
      return floor_div((int64_t)reference.level * m, (uint32_t)nr);
    }
    default:  // REF_CONSTANT
      return reference.level;
  }
}

static inline int8_t sign_of(int32_t x) { return (x > 0) - (x < 0); }

// The feedforward's sum kn r(k+P) + kc r(k+P-1) + k0 + kf sign r(k+P), gains at g.
static int64_t feedforward_sum(uint32_t k, const int32_t *g) {
  int32_t r1 = reference_at(k + control.preview);
  int32_t r0 = reference_at(k + control.preview - 1);
  return (int64_t)g[0] * r1 + (int64_t)g[1] * r0 + g[2] + (int64_t)g[3] * sign_of(r1);
}

static inline int64_t round_shift(int64_t acc) { return (acc + (1L << (GAIN_BITS - 1))) >> GAIN_BITS; }

static int16_t clip_duty(int64_t u) {
  if (u > cfg.duty_limit) return cfg.duty_limit;
  if (u < -cfg.duty_limit) return -cfg.duty_limit;
  return (int16_t)u;
}

static void control_reset(void) {
  memset(&cs, 0, sizeof(cs));
  cs.n_history = control.kind == CTRL_MPC || control.kind == CTRL_LQR ? control.n - 4
               : control.kind == CTRL_LQR_INTEGRAL ? control.n - 5
               : control.kind == CTRL_LQR_POSITION ? control.n - 3 : 1;
}

// The integral LQR's sum of the errors r(k) - 16 y, updated after its duty's acc: the PI's
// anti-windup (no integration further into the duty limit). Its own frame, not the ISR's.
static void __attribute__((noinline)) integrate_error(uint32_t k, int32_t y, int64_t acc) {
  int32_t err = reference_at(k) - y * SPEED_REFERENCE_SCALE;
  int64_t raw = round_shift(acc);
  if (!((raw > cfg.duty_limit && err > 0) || (raw < -cfg.duty_limit && err < 0))) cs.integral += err;
}

// The duty of sample k from the counts read at k (integer arithmetic only).
static int16_t control_step(uint32_t k, int32_t counts) {
  if (k == 0) cs.previous = cs.origin = counts;
  int32_t y = counts - cs.previous;
  cs.previous = counts;
  const int32_t *g = control.gains;
  int64_t acc;
  switch (control.kind) {
    case CTRL_MPC:
    case CTRL_LQR:
    case CTRL_LQR_INTEGRAL: {  // one linear form; only the design of the gains differs
      const int32_t *f = g + (control.kind == CTRL_LQR_INTEGRAL);  // the integral's ki sits after ky
      int32_t r = reference_at(k + control.preview);
      acc = (int64_t)g[0] * r + (int64_t)g[1] * y + f[2] + (int64_t)f[3] * sign_of(r);
      for (uint8_t m = 0; m < cs.n_history; m++) acc += (int64_t)f[4 + m] * cs.history[m];
      if (f != g) integrate_error(k, y, acc += (int64_t)g[2] * cs.integral);  // ki times the sum before k
      break;
    }
    case CTRL_PI: {
      int32_t err = reference_at(k) - y * SPEED_REFERENCE_SCALE;
      int64_t integral = cs.integral + err;
      acc = (int64_t)g[0] * err + (int64_t)g[1] * integral;
      if (control.n == 6) acc += feedforward_sum(k, g + 2);
      int64_t raw = round_shift(acc);
      if (!((raw > cfg.duty_limit && err > 0) || (raw < -cfg.duty_limit && err < 0))) cs.integral = integral;
      break;
    }
    case CTRL_POSITION:
      acc = (int64_t)g[0] * (reference_at(k) - (counts - cs.origin)) - (int64_t)g[1] * y;
      break;
    case CTRL_LQR_POSITION:
      acc = (int64_t)g[0] * (reference_at(k + control.preview) - (counts - cs.origin)) + (int64_t)g[1] * y + g[2];
      for (uint8_t m = 0; m < cs.n_history; m++) acc += (int64_t)g[3 + m] * cs.history[m];
      break;
    default:  // CTRL_FEEDFORWARD
      acc = feedforward_sum(k, g);
      break;
  }
  int16_t u = clip_duty(round_shift(acc));
  for (uint8_t m = cs.n_history - 1; m > 0; m--) cs.history[m] = cs.history[m - 1];
  cs.history[0] = u;
  return u;
}

// ---------------------------------------------------------------------------------------------
// Sample clock: Timer 1, CTC, prescaler 8 (0.5 us). Periods above 32.768 ms are split into
// sub_count sub-intervals (sub_long of length q + 1, the rest q) so every tick stays exact.

static void timer_stop(void) {
  TIMSK1 = 0;
  TCCR1B = 0;
}

// Stop the run with duty 0. Interrupts must be off.
static void stop_run(uint8_t reason) {
  apply_duty(0);
  timer_stop();
  if (running) {
    running = 0;
    errors_at_stop = enc_errors;
    end_reason = reason;
    end_pending = 1;
  }
}

// Split the period into Timer 1 sub-intervals. Called with interrupts on: the 32-bit
// divisions take ~80 us, too long to hold off the encoder.
static void timer_plan(uint32_t period_us) {
  uint32_t ticks = period_us * (F_CPU / 1000000UL / 8);
  uint8_t m = (ticks + 65535UL) / 65536UL;
  sub_count = m;
  sub_len_q = ticks / m - 1;            // OCR value for a sub-interval of q ticks
  sub_long = ticks % m;                 // the first sub_long sub-intervals last q + 1
}

// The instant of a tick, in Timer 1 counts (0.5 us) after its compare: the duty is written and the
// count read then, however late the interrupt started. Its start waits for the interrupts
// running or pending (an encoder edge, the UART, Timer 0: a few us each, chained, and they may
// preempt its prologue), likelier the faster the motor turns and the busier the line, so a duty
// written and a count read at its start were taken at instants that jittered with the speed,
// which no model of the motor has. Under emulation the interrupt reaches its wait 7 us after the
// compare, 35 us at worst seen (a 500 us period at 500000 baud): the instant is 40 us after the
// compare (a tick starting later takes its instant when it starts). From its wait to the instant
// interrupts are off, so nothing can delay the instant, and the wait decodes the encoder itself
// (an edge is counted within about 1 us, sooner than by its interrupt), an edge in the last
// TICK_LAST_POLL counts at the instant from the pins. The UART loses nothing: a byte received
// waits in its two-byte buffer, and one to send waits for the instant (at 500000 baud, a byte
// every 20 us, the line may idle for up to 15 us a tick).
#define TICK_INSTANT 80
#define TICK_LAST_POLL 8

// Start the sample clock planned by timer_plan(). Interrupts must be off.
static void timer_start(void) {
  sub_pos = 0;
  TCCR1A = 0;
  TCCR1B = 0;
  TCNT1 = 0;
  OCR1A = sub_len_q + (sub_long ? 1 : 0);
  OCR1B = TICK_INSTANT;                 // its flag (no interrupt) marks a tick's instant
  TIFR1 = _BV(OCF1A);
  TIMSK1 = _BV(OCIE1A);
  TCCR1B = _BV(WGM12) | _BV(CS11);      // CTC on OCR1A, clk/8
}

// ISR_NOBLOCK: interrupts are back on from the first instruction, and after the snapshot at the
// instant; in between this interrupt decodes the encoder itself. This
// interrupt cannot re-enter: the next compare is a whole period (>= 100 us) away, and it masks
// itself before the long part.
ISR(TIMER1_COMPA_vect, ISR_NOBLOCK) {
  if (sub_count > 1) {
    sub_pos++;
    if (sub_pos < sub_count) {
      OCR1A = sub_len_q + (sub_pos < sub_long ? 1 : 0);
      return;
    }
    sub_pos = 0;
    OCR1A = sub_len_q + (sub_long ? 1 : 0);
  }
  if (!running) return;
  TIMSK1 = 0;
  // 1. at the tick's instant (TICK_INSTANT), apply the duty latched at the previous tick (duty 0
  //    at tick 0) and snapshot the counts: three adjacent instructions read the pins and write
  //    the duty's magnitude and direction (in assembly, so that the compiler puts nothing
  //    between them: a cycle apart, the count's instant is the duty's, and a sign change drives
  //    the new magnitude the old way for one cycle; IN2 of an IN1/IN2 bridge follows). The count
  //    is the pins': an edge since the last one counted is counted here from the pins, not from
  //    its interrupt flag (an edge between reading the flag and the pins would be missed), the
  //    flag cleared first so that a later edge still interrupts. After the last sample the duty
  //    stays as it is until stop_run() zeroes it.
  uint8_t live = tick_index < cfg.n_samples;    // only this ISR changes tick_index during a run
  uint8_t magnitude = live ? next_magnitude : PWM_OCR;
  uint8_t counted = enc_decoding == 4 ? 3 : 2;  // the pins whose change interrupts: A and B, or A
  cli();
  volatile uint8_t *direction = dir_port;
  uint8_t direction_value = live ? latched_direction_port() : *direction;
  TIFR1 = _BV(OCF1B);                           // a compare B of an earlier (sub-)period
  if (TCNT1 < TICK_INSTANT) {                   // (a tick that started after its instant: now)
    while (TCNT1 < TICK_INSTANT - TICK_LAST_POLL) {   // the encoder decoded here meanwhile
      uint8_t now = encoder_pins();
      if ((now ^ (enc_previous >> 2)) & counted) encoder_step(now);
    }
    while (!(TIFR1 & _BV(OCF1B))) {}            // 3 cycles a turn: the instant to 3 cycles
  }
  PCIFR = _BV(ENC_PCIE);   // PCIFn is PCIEn's bit: cleared, an edge from here on interrupts
  uint8_t pins;
  __asm__ __volatile__("in %0, %1\n\tsts %2, %3\n\tst %a4, %5"
                       : "=&r"(pins)
                       : "I"(_SFR_IO_ADDR(ENC_PIN_REG)), "n"(_SFR_MEM_ADDR(PWM_OCR)), "r"(magnitude),
                         "e"(direction), "r"(direction_value)
                       : "memory");
#if DRIVER_TYPE == DRIVER_IN1_IN2
  if (live) apply_latched_in2();
#endif
  uint8_t now = encoder_bits(pins);
  if ((now ^ (enc_previous >> 2)) & counted) encoder_step(now);
  int32_t counts = enc_count;
  uint32_t errors = enc_errors;
  uint32_t now_us = micros();
  sei();
  if (tick_index >= cfg.n_samples) {   // one period after the last sample: done
    cli();
    stop_run(END_COMPLETE);
    return;
  }
  // 2. this sample's duty: the controller's from the counts just read, or the waveform's;
  //    applied at the next tick
  int16_t duty = control.kind ? control_step(tick_index, counts) : (int16_t)wave_next();
  // 3. queue the sample, or drop and count it (only this ISR writes the queue head)
  uint8_t flags = tick_late;
  tick_late = 0;
  uint32_t new_errors = errors - errors_at_last_sample;
  errors_at_last_sample = errors;
  if (new_errors) flags |= FLAG_ENCODER_ERROR;
  uint8_t head = queue_head;
  uint8_t next = head + 1 == SAMPLE_QUEUE_LEN ? 0 : head + 1;
  if (next == queue_tail) {
    samples_dropped++;
    if (!overflow_reported) {
      overflow_reported = 1;
      if (!fault_code) { fault_code = FAULT_QUEUE_OVERFLOW; fault_index = tick_index; }
    }
  } else {
    Sample *s = &queue[head];
    s->index = tick_index;
    s->time_us = now_us;
    s->counts = counts;
    s->duty = duty;
    s->flags = flags;
    queue_head = next;
  }
  tick_index++;
  if (new_errors > 255) {
    cli();
    fault_code = FAULT_ENCODER;
    fault_index = tick_index - 1;
    stop_run(END_FAULT);
    return;
  }
  // 4. latch the duty for the next tick
  cli();
  latch_duty(duty);
  if (sub_count == 1 && (TIFR1 & _BV(OCF1A))) {  // the next tick is already due: it is late
    tick_late = FLAG_LATE;
    if (tick_overruns != 0xFFFF) tick_overruns++;
  }
  if (running) TIMSK1 = _BV(OCIE1A);
}

// ---------------------------------------------------------------------------------------------
// Framing: COBS + CRC-16/CCITT-FALSE (little-endian on the wire).

static uint16_t crc16(const uint8_t *data, uint8_t len) {
  uint16_t crc = 0xFFFF;
  for (uint8_t i = 0; i < len; i++) crc = _crc_xmodem_update(crc, data[i]);
  return crc;
}

// Decode COBS in[0..n) into out; returns the body length, or -1 if malformed.
static int16_t cobs_decode(const uint8_t *in, uint8_t n, uint8_t *out) {
  uint8_t i = 0, o = 0;
  while (i < n) {
    uint8_t code = in[i++];
    if (code == 0) return -1;
    for (uint8_t j = 1; j < code; j++) {
      if (i >= n || o >= MAX_BODY) return -1;
      out[o++] = in[i++];
    }
    if (code != 0xFF && i < n) {
      if (o >= MAX_BODY) return -1;
      out[o++] = 0;
    }
  }
  return o;
}

// Send one frame if the serial transmit buffer has room; returns 1 if sent.
static uint8_t send_frame(uint8_t type, const uint8_t *payload, uint8_t len) {
  uint8_t body[MAX_BODY];
  if (Serial.availableForWrite() < len + 4 + 3) return 0;
  body[0] = type;
  body[1] = tx_frame_seq;
  for (uint8_t i = 0; i < len; i++) body[2 + i] = payload[i];
  uint16_t crc = crc16(body, len + 2);
  put_u16(body + 2 + len, crc);
  uint8_t blen = len + 4;
  // COBS, written block by block (no second buffer on the stack): each block is the bytes up
  // to the next zero, preceded by their count + 1. A body is at most 64 bytes < 254.
  uint8_t i = 0;
  for (;;) {
    uint8_t j = i;
    while (j < blen && body[j] != 0) j++;
    Serial.write((uint8_t)(j - i + 1));
    Serial.write(body + i, j - i);
    if (j == blen) break;
    i = j + 1;
  }
  Serial.write((uint8_t)0);
  tx_frame_seq++;
  return 1;
}

static void respond(uint8_t type, uint8_t ref_type, uint8_t ref_frame_seq, uint8_t reason) {
  uint8_t next = (resp_head + 1) % RESPONSE_QUEUE_LEN;
  if (next == resp_tail) return;  // the host sent 8 commands without reading: it will time out
  responses[resp_head].type = type;
  responses[resp_head].ref_type = ref_type;
  responses[resp_head].ref_frame_seq = ref_frame_seq;
  responses[resp_head].reason = reason;
  resp_head = next;
}

// ---------------------------------------------------------------------------------------------
// Commands

static uint8_t level_ok(int16_t x) { return x >= -MAX_LEVEL && x <= MAX_LEVEL; }

// An invalid WAVE (its length cannot be checked: unknown kind, multisine n outside 1...4) that
// PROTOCOL.md says to NAK with BAD_VALUE; like BAD_LENGTH it is counted in rx_errors.
#define INVALID_BAD_VALUE (0x80 | NAK_BAD_VALUE)

// Validate and store a WAVE payload; returns 0, a NAK reason, or INVALID_BAD_VALUE.
static uint8_t parse_wave(const uint8_t *p, uint8_t len, uint8_t check_only) {
  if (len < 1) return NAK_BAD_LENGTH;
  Wave w;
  memset(&w, 0, sizeof(w));
  w.kind = p[0];
  p++;
  len--;
  switch (w.kind) {
    case WAVE_CONSTANT:
      if (len != 2) return NAK_BAD_LENGTH;
      w.level_a = get_u16(p);
      if (!level_ok(w.level_a)) return NAK_BAD_VALUE;
      break;
    case WAVE_STEP:
      if (len != 8) return NAK_BAD_LENGTH;
      w.level_a = get_u16(p);
      w.level_b = get_u16(p + 2);
      w.word_a = get_u32(p + 4);
      if (!level_ok(w.level_a) || !level_ok(w.level_b)) return NAK_BAD_VALUE;
      break;
    case WAVE_MULTISINE:
      if (len < 3) return NAK_BAD_LENGTH;
      w.level_a = get_u16(p);
      w.n = p[2];
      if (w.n < 1 || w.n > MAX_COMPONENTS) return INVALID_BAD_VALUE;
      if (len != 3 + 10 * w.n) return NAK_BAD_LENGTH;
      if (!level_ok(w.level_a)) return NAK_BAD_VALUE;
      for (uint8_t j = 0; j < w.n; j++) {
        const uint8_t *c = p + 3 + 10 * j;
        w.comp[j].amplitude = get_u16(c);
        w.comp[j].phase0 = get_u32(c + 2);
        w.comp[j].phase_inc = get_u32(c + 6);
        if (!level_ok(w.comp[j].amplitude)) return NAK_BAD_VALUE;
      }
      break;
    case WAVE_CHIRP:
      if (len != 16) return NAK_BAD_LENGTH;
      w.level_a = get_u16(p);
      w.level_b = get_u16(p + 2);
      w.word_a = get_u32(p + 4);
      w.word_b = get_u32(p + 8);
      w.word_c = (int32_t)get_u32(p + 12);
      if (!level_ok(w.level_a) || !level_ok(w.level_b)) return NAK_BAD_VALUE;
      break;
    case WAVE_PRBS:
      if (len != 9) return NAK_BAD_LENGTH;
      w.level_a = get_u16(p);
      w.level_b = get_u16(p + 2);
      w.n = p[4];
      w.seed = get_u16(p + 5);
      w.hold = get_u16(p + 7);
      if (!level_ok(w.level_a) || !level_ok(w.level_b)) return NAK_BAD_VALUE;
      if (w.n < 2 || w.n > 16 || w.hold < 1 || w.seed == 0) return NAK_BAD_VALUE;
      if (w.n < 16 && w.seed >= (1U << w.n)) return NAK_BAD_VALUE;
      break;
    case WAVE_ODD_MULTISINE:
      if (len != 9) return NAK_BAD_LENGTH;
      w.level_a = get_u16(p);
      w.level_b = get_u16(p + 2);
      w.n = p[4];
      w.max_harmonic = p[5];
      w.seed = get_u16(p + 6);
      w.group = p[8];
      if (!level_ok(w.level_a) || w.level_b < 1 || w.level_b > MAX_LEVEL) return NAK_BAD_VALUE;
      if (w.n < 4 || w.n > 16 || !(w.max_harmonic & 1)) return NAK_BAD_VALUE;
      if ((uint32_t)w.max_harmonic >= (1UL << w.n) / 2 || (w.max_harmonic + 1) / 2 > MAX_ODD_LINES) return NAK_BAD_VALUE;
      if (w.group == 1 || w.group > 16) return NAK_BAD_VALUE;
      break;
    default:
      return INVALID_BAD_VALUE;
  }
  if (!check_only) wave = w;
  return 0;
}

// Validate and store a CONTROL payload; returns 0 or a NAK reason.
static uint8_t parse_control(const uint8_t *p, uint8_t len, uint8_t check_only) {
  if (len < 3) return NAK_BAD_LENGTH;
  uint8_t kind = p[0], preview = p[1], n = p[2];
  if (n > MAX_GAINS || len != 3 + 4 * n) return NAK_BAD_LENGTH;
  uint8_t ok = kind == CTRL_NONE ? n == 0
             : kind == CTRL_MPC ? n >= 5
             : kind == CTRL_PI ? (n == 2 || n == 6)
             : kind == CTRL_POSITION ? n == 2
             : kind == CTRL_FEEDFORWARD ? n == 4
             : kind == CTRL_LQR ? n >= 5
             : kind == CTRL_LQR_POSITION ? n >= 4
             : kind == CTRL_LQR_INTEGRAL ? n >= 6 : 0;
  if (!ok || preview > MAX_GAINS) return NAK_BAD_VALUE;
  if (check_only) return 0;
  control.kind = kind;
  control.preview = preview;
  control.n = n;
  for (uint8_t i = 0; i < n; i++) control.gains[i] = (int32_t)get_u32(p + 3 + 4 * i);
  return 0;
}

static uint8_t ref_ok(int32_t x) { return x >= -MAX_REFERENCE && x <= MAX_REFERENCE; }

// Validate and store a REFERENCE payload; returns 0, a NAK reason, or INVALID_BAD_VALUE.
static uint8_t parse_reference(const uint8_t *p, uint8_t len, uint8_t check_only) {
  if (len < 1) return NAK_BAD_LENGTH;
  Reference r;
  memset(&r, 0, sizeof(r));
  r.kind = p[0];
  p++;
  len--;
  switch (r.kind) {
    case REF_CONSTANT:
      if (len != 4) return NAK_BAD_LENGTH;
      r.level = (int32_t)get_u32(p);
      break;
    case REF_STEP:
      if (len != 12) return NAK_BAD_LENGTH;
      r.before = (int32_t)get_u32(p);
      r.level = (int32_t)get_u32(p + 4);
      r.start = get_u32(p + 8);
      break;
    case REF_MULTISINE: {
      if (len < 5) return NAK_BAD_LENGTH;
      r.level = (int32_t)get_u32(p);
      r.n = p[4];
      if (r.n < 1 || r.n > MAX_COMPONENTS) return INVALID_BAD_VALUE;
      if (len != 5 + 12 * r.n) return NAK_BAD_LENGTH;
      int32_t total = 0;
      for (uint8_t j = 0; j < r.n; j++) {
        const uint8_t *c = p + 5 + 12 * j;
        r.comp[j].amplitude = (int32_t)get_u32(c);
        r.comp[j].phase0 = get_u32(c + 4);
        r.comp[j].phase_inc = get_u32(c + 8);
        if (!ref_ok(r.comp[j].amplitude)) return NAK_BAD_VALUE;
        total += r.comp[j].amplitude < 0 ? -r.comp[j].amplitude : r.comp[j].amplitude;
      }
      if (total > MAX_REFERENCE) return NAK_BAD_VALUE;
      break;
    }
    case REF_TRAPEZOID:
      if (len != 16) return NAK_BAD_LENGTH;
      r.level = (int32_t)get_u32(p);
      r.start = get_u32(p + 4);
      r.ramp = get_u32(p + 8);
      r.hold = get_u32(p + 12);
      if (r.ramp < 1 || r.ramp > 0x3FFFFFFFUL || r.hold > 0x3FFFFFFFUL) return NAK_BAD_VALUE;
      break;
    default:
      return INVALID_BAD_VALUE;
  }
  if (!ref_ok(r.level) || !ref_ok(r.before)) return NAK_BAD_VALUE;
  if (!check_only) reference = r;
  return 0;
}

static uint8_t parse_config(const uint8_t *p) {
  Config c;
  c.sample_period_us = get_u32(p);
  c.n_samples = get_u32(p + 4);
  c.duty_limit = (int16_t)get_u16(p + 8);
  c.decoding = p[10];
  c.watchdog_ms = get_u16(p + 11);
  if (c.sample_period_us < 100 || c.sample_period_us > 1000000UL) return NAK_BAD_VALUE;
  if (c.n_samples < 1) return NAK_BAD_VALUE;
  if (c.duty_limit < 0 || c.duty_limit > 255) return NAK_BAD_VALUE;
  if (c.decoding != 1 && c.decoding != 2 && c.decoding != 4) return NAK_BAD_VALUE;
  if (c.watchdog_ms != 0 && (c.watchdog_ms < 50 || c.watchdog_ms > 60000U)) return NAK_BAD_VALUE;
  cfg = c;
  control.kind = CTRL_NONE;  // CONFIG returns to open loop; CONTROL comes after it
  return 0;
}

static void start_run(void) {
  setup_encoder(cfg.decoding);
  if (control.kind) {
    control_reset();
  } else {
    wave_reset();
  }
  timer_plan(cfg.sample_period_us);
  cli();
  queue_head = queue_tail = 0;
  tick_index = 0;
  latch_duty(0);
  tick_late = 0;
  tick_overruns = 0;
  samples_dropped = 0;
  errors_at_start = errors_at_last_sample = enc_errors;
  fault_code = 0;
  overflow_reported = 0;
  end_pending = 0;
  running = 1;
  timer_start();
  sei();
  samples_sent = 0;
  rx_errors = 0;
  last_rx_ms = millis();
}

// Only valid frames (known type, right length) show the host is alive (PROTOCOL.md).
static void host_alive(void) { last_rx_ms = millis(); }

// Answer a frame that sets up the next run (WAVE, CONTROL, REFERENCE) from its parser's result
// r; on success set *have (when given).  Returns 0 for a wrong payload length, which the caller
// answers like every other (NAK_BAD_LENGTH).  An invalid value is a receive error and does not
// show the host is alive; a busy device refuses the frame without storing it.
static uint8_t answer_setup(uint8_t type, uint8_t frame_seq, uint8_t r, uint8_t busy, uint8_t *have) {
  if (r == NAK_BAD_LENGTH) return 0;
  if (r == INVALID_BAD_VALUE) {
    rx_errors++;
    respond(T_NAK, type, frame_seq, NAK_BAD_VALUE);
    return 1;
  }
  host_alive();
  if (busy) respond(T_NAK, type, frame_seq, NAK_BUSY);
  else if (r) respond(T_NAK, type, frame_seq, r);
  else {
    if (have) *have = 1;
    respond(T_ACK, type, frame_seq, 0);
  }
  return 1;
}

static void handle_frame(uint8_t type, uint8_t frame_seq, const uint8_t *p, uint8_t len) {
  uint8_t busy = running;
  switch (type) {
    case T_HELLO:
      if (len != 1) break;
      host_alive();
      if (busy) respond(T_NAK, type, frame_seq, NAK_BUSY);
      else respond(T_HELLO_ACK, type, frame_seq, 0);
      return;
    case T_CONFIG: {
      if (len != 13) break;
      host_alive();
      if (busy) { respond(T_NAK, type, frame_seq, NAK_BUSY); return; }
      uint8_t r = parse_config(p);
      if (r) respond(T_NAK, type, frame_seq, r);
      else { have_config = 1; respond(T_ACK, type, frame_seq, 0); }
      return;
    }
    case T_WAVE:
      if (answer_setup(type, frame_seq, parse_wave(p, len, busy), busy, &have_wave)) return;
      break;
    case T_CONTROL:
      if (answer_setup(type, frame_seq, parse_control(p, len, busy), busy, 0)) return;
      break;
    case T_REFERENCE:
      if (answer_setup(type, frame_seq, parse_reference(p, len, busy), busy, &have_reference)) return;
      break;
    case T_START:
      if (len != 0) break;
      host_alive();
      if (busy) { respond(T_NAK, type, frame_seq, NAK_BUSY); return; }
      if (!have_config || !(control.kind ? have_reference : have_wave)) {
        respond(T_NAK, type, frame_seq, NAK_NOT_CONFIGURED);
        return;
      }
      respond(T_ACK, type, frame_seq, 0);
      start_run();
      return;
    case T_STOP:
      if (len != 0) break;
      host_alive();
      cli();
      stop_run(END_STOPPED);
      sei();
      respond(T_ACK, type, frame_seq, 0);
      return;
    case T_HEARTBEAT:
      if (len != 0) break;
      host_alive();
      return;
    default:  // unknown, or a device-to-host type
      rx_errors++;
      respond(T_NAK, type, frame_seq, NAK_UNKNOWN_TYPE);
      return;
  }
  // A known type with the wrong payload length.
  rx_errors++;
  respond(T_NAK, type, frame_seq, NAK_BAD_LENGTH);
}

// A complete frame (delimiter excluded) has arrived in rx_buf.
static void receive_frame(void) {
  uint8_t body[MAX_BODY];
  int16_t n = cobs_decode(rx_buf, rx_len, body);
  if (n < 4) { rx_errors++; return; }
  uint16_t crc = get_u16(body + n - 2);
  if (crc16(body, n - 2) != crc) { rx_errors++; return; }
  uint8_t type = body[0];
  handle_frame(type, body[1], body + 2, n - 4);
}

static void receive_byte(uint8_t b) {
  if (b == 0) {
    if (!rx_discarding && rx_len > 0) receive_frame();
    rx_len = 0;
    rx_discarding = 0;
    return;
  }
  if (rx_discarding) return;
  if (rx_len >= MAX_ENCODED) {
    rx_errors++;
    rx_discarding = 1;
    rx_len = 0;
    return;
  }
  rx_buf[rx_len++] = b;
}

// ---------------------------------------------------------------------------------------------
// Transmit: at most one frame per loop() pass, in priority order.

static void transmit(void) {
  uint8_t p[21];
  if (boot_pending) {
    // A lone 0x00 first: if the reset cut a frame short, the host drops that partial frame
    // here instead of gluing it to BOOT (zero-length frames are ignored).
    if (Serial.availableForWrite() < 2 + 4 + 3 + 1) return;
    Serial.write((uint8_t)0);
    p[0] = PROTOCOL_VERSION;
    p[1] = reset_cause;
    if (send_frame(T_BOOT, p, 2)) boot_pending = 0;
    return;
  }
  if (resp_tail != resp_head) {
    Response *r = &responses[resp_tail];
    uint8_t ok;
    if (r->type == T_HELLO_ACK) {
      uint8_t *q = p;
      *q++ = PROTOCOL_VERSION;
      q = put_u16(q, FIRMWARE_VERSION);
      q = put_u32(q, F_CPU);
      *q++ = reset_cause;
      *q++ = MAX_PAYLOAD;
      const char *name = BOARD_NAME;
      for (uint8_t i = 0; i < 8; i++) {
        *q++ = *name ? *name : 0;
        if (*name) name++;
      }
      put_u32(q, ENCODER_COUNTS_PER_REV);
      ok = send_frame(T_HELLO_ACK, p, 21);
    } else if (r->type == T_ACK) {
      p[0] = r->ref_type;
      p[1] = r->ref_frame_seq;
      ok = send_frame(T_ACK, p, 2);
    } else {
      p[0] = r->ref_type;
      p[1] = r->ref_frame_seq;
      p[2] = r->reason;
      ok = send_frame(T_NAK, p, 3);
    }
    if (ok) resp_tail = (resp_tail + 1) % RESPONSE_QUEUE_LEN;
    return;
  }
  uint8_t code;
  uint32_t index;
  cli();
  code = fault_code;
  index = fault_index;
  sei();
  if (code) {
    p[0] = code;
    put_u32(p + 1, index);
    if (send_frame(T_FAULT, p, 5)) {
      cli();
      if (fault_code == code && fault_index == index) fault_code = 0;
      sei();
    }
    return;
  }
  if (queue_tail != queue_head) {
    Sample *s = &queue[queue_tail];
    uint8_t *q = p;
    q = put_u32(q, s->index);
    q = put_u32(q, s->time_us);
    q = put_u32(q, (uint32_t)s->counts);
    q = put_u16(q, (uint16_t)s->duty);
    *q = s->flags;
    if (send_frame(T_SAMPLE, p, 15)) {
      samples_sent++;
      queue_tail = queue_tail + 1 == SAMPLE_QUEUE_LEN ? 0 : queue_tail + 1;
    }
    return;
  }
  if (end_pending && !running) {
    uint32_t dropped, errors;
    uint16_t overruns;
    cli();
    dropped = samples_dropped;
    errors = errors_at_stop - errors_at_start;
    overruns = tick_overruns;
    sei();
    uint8_t *q = p;
    *q++ = end_reason;
    q = put_u32(q, samples_sent);
    q = put_u32(q, dropped);
    q = put_u32(q, errors);
    q = put_u16(q, rx_errors);
    put_u16(q, overruns);
    if (send_frame(T_END, p, 17)) end_pending = 0;
  }
}

// ---------------------------------------------------------------------------------------------

void setup() {
  reset_cause = boot_mcusr ? boot_mcusr : boot_r2;
  setup_bridge();  // first: duty 0 before anything else can take time
  pinMode(PIN_ENC_A, INPUT_PULLUP);
  pinMode(PIN_ENC_B, INPUT_PULLUP);
  setup_encoder(4);
  Serial.begin(BAUD_RATE);
  wdt_enable(WDTO_250MS);  // fed only from loop(): a stuck loop resets the board (pins float)
}

void loop() {
  wdt_reset();
  // Receive: bounded number of bytes per pass.
  for (uint8_t n = 0; n < 32 && Serial.available() > 0; n++) receive_byte((uint8_t)Serial.read());
  // Host-silence watchdog (emulated or real time alike: millis() counts device time).
  if (running && cfg.watchdog_ms && (uint32_t)(millis() - last_rx_ms) > cfg.watchdog_ms) {
    cli();
    if (running) {
      stop_run(END_WATCHDOG);
      fault_code = FAULT_HOST_SILENCE;
      fault_index = tick_index;
    }
    sei();
  }
  transmit();
}
