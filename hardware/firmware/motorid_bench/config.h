// motorid bench firmware: the one file to edit for your wiring.
// Every setting can also be overridden from the compiler command line (-DNAME=value).
#ifndef MOTORID_CONFIG_H
#define MOTORID_CONFIG_H

// ---- H-bridge type -------------------------------------------------------------------------
// DRIVER_DIR_PWM : one PWM pin (speed) + one DIR pin (Cytron MD10C/MD13S, Pololu DRV8838/G2,
//                  TB6612 with AIN2 driven through an inverter, ...).
// DRIVER_IN1_IN2 : one PWM/enable pin (L298N ENA, TB6612 PWMA) + two direction inputs
//                  IN1/IN2 (L298N IN1/IN2, TB6612 AIN1/AIN2; tie TB6612 STBY high).
#define DRIVER_DIR_PWM 1
#define DRIVER_IN1_IN2 2
#ifndef DRIVER_TYPE
#define DRIVER_TYPE DRIVER_DIR_PWM
#endif

// ---- Pins (Arduino Uno numbering) ------------------------------------------------------------
// PWM must be a Timer 2 output: 11 (OC2A) or 3 (OC2B). Timer 0 keeps millis()/micros(),
// Timer 1 is the sample clock. Put a 10 kOhm pull-down on this pin (see README).
#ifndef PIN_PWM
#define PIN_PWM 11
#endif
#ifndef PIN_DIR          // DRIVER_DIR_PWM only
#define PIN_DIR 8
#endif
#ifndef PIN_IN1          // DRIVER_IN1_IN2 only
#define PIN_IN1 8
#endif
#ifndef PIN_IN2          // DRIVER_IN1_IN2 only
#define PIN_IN2 9
#endif
// Encoder A and B: any two pins of the same port (0-7, 8-13 or A0-A5 = 14-19); they are
// decoded by a pin-change interrupt reading the port register directly.
#ifndef PIN_ENC_A
#define PIN_ENC_A 2
#endif
#ifndef PIN_ENC_B
#define PIN_ENC_B 3
#endif

// Level of the DIR pin (or of IN1, with IN2 the opposite) for a positive duty. Swap it (or the
// motor leads) if a positive duty makes the encoder count down.
#ifndef DIR_FORWARD_LEVEL
#define DIR_FORWARD_LEVEL 1
#endif

// Timer 2 phase-correct PWM frequency = F_CPU / (510 * prescaler).
// 1: 31.4 kHz (inaudible; TB6612, Cytron), 8: 3.9 kHz (L298N, slow bipolar bridges), 64: 490 Hz.
#ifndef PWM_PRESCALER
#define PWM_PRESCALER 1
#endif

// ---- Link ------------------------------------------------------------------------------------
// Must equal the host's baud rate (SerialRig default 250000). 250000 and 500000 are exact at
// 16 MHz; 115200 is 2.1 % fast on an Uno, which its USB bridge tolerates.
#ifndef BAUD_RATE
#define BAUD_RATE 250000
#endif

// ---- Sizes -----------------------------------------------------------------------------------
// SAMPLE frames waiting for the serial line; 15 bytes of RAM each.
#ifndef SAMPLE_QUEUE_LEN
#define SAMPLE_QUEUE_LEN 40
#endif
// Reported in HELLO_ACK (at most 8 ASCII characters).
#ifndef BOARD_NAME
#define BOARD_NAME "uno"
#endif
// Encoder counts per revolution after x4 decoding, reported in HELLO_ACK so the host uses it
// (0: not set here; the host then uses its own --counts-per-rev).
#ifndef ENCODER_COUNTS_PER_REV
#define ENCODER_COUNTS_PER_REV 0
#endif

#endif
