# Firmware and AVR-emulation targets, included by the top-level Makefile.
#   make firmware       hardware/firmware/build/motorid_bench.{elf,hex} (gcc-avr + Debian's Arduino core)
#   make avr-sim        hardware/sim/build/motorid-avr-sim (libsimavr harness)
#   make firmware-deps  apt-get install the Debian packages, only those missing (sudo when not root)
# firmware and avr-sim run firmware-deps first; FIRMWARE_DEPS= (empty) skips it, as the Python
# launcher does (it reports missing tools instead of installing packages).
# FIRMWARE_DEFS adds -D settings (e.g. FIRMWARE_DEFS=-DBAUD_RATE=500000 FIRMWARE_BUILD=...).

AVR_PACKAGES   := gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev libsimavrparts1 \
                  libelf-dev pkg-config build-essential
ARDUINO_CORE   ?= /usr/share/arduino/hardware/arduino/avr
FIRMWARE_SRC   := hardware/firmware/motorid_bench
FIRMWARE_BUILD ?= hardware/firmware/build
FIRMWARE_DEFS  ?=
SIM_BUILD      := hardware/sim/build
AVR_CC         := avr-gcc
AVR_CXX        := avr-g++
AVR_FLAGS      := -mmcu=atmega328p -DF_CPU=16000000L -DARDUINO=10807 -DARDUINO_AVR_UNO \
                  -DARDUINO_ARCH_AVR -DDECIMAL_DIG=__DECIMAL_DIG__ -Os -Wall \
                  -ffunction-sections -fdata-sections \
                  -I$(ARDUINO_CORE)/cores/arduino -I$(ARDUINO_CORE)/variants/standard
AVR_CXXFLAGS   := $(AVR_FLAGS) -std=gnu++11 -fno-exceptions -fno-threadsafe-statics -fpermissive
CORE_SOURCES   := $(wildcard $(ARDUINO_CORE)/cores/arduino/*.c $(ARDUINO_CORE)/cores/arduino/*.cpp \
                            $(ARDUINO_CORE)/cores/arduino/*.S)
FIRMWARE_ELF   := $(FIRMWARE_BUILD)/motorid_bench.elf
SIM_BIN        := $(SIM_BUILD)/motorid-avr-sim
FIRMWARE_DEPS  ?= firmware-deps

.PHONY: firmware avr-sim firmware-deps firmware-size

# Debian/Ubuntu only; as root (as in CI) or through sudo. Installs nothing when all are present.
firmware-deps:
	@missing=""; for p in $(AVR_PACKAGES); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if ! command -v apt-get >/dev/null 2>&1; then \
	    echo "firmware-deps: apt-get not found; install the equivalents of:$$missing" >&2; exit 1; fi; \
	  sudo=""; [ "$$(id -u)" = 0 ] || sudo="sudo"; \
	  echo "installing:$$missing"; \
	  $$sudo apt-get update -qq && $$sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	fi

firmware: $(FIRMWARE_DEPS)
	@$(MAKE) --no-print-directory $(FIRMWARE_ELF) $(FIRMWARE_BUILD)/motorid_bench.hex

avr-sim: $(FIRMWARE_DEPS)
	@$(MAKE) --no-print-directory $(SIM_BIN)

firmware-size: firmware
	avr-size -C --mcu=atmega328p $(FIRMWARE_ELF)

# The core is compiled object by object into one archive (rebuilt only when missing).
$(FIRMWARE_BUILD)/core.a:
	mkdir -p $(FIRMWARE_BUILD)/core
	set -e; for src in $(CORE_SOURCES); do \
	  obj=$(FIRMWARE_BUILD)/core/$$(basename $$src).o; \
	  case $$src in \
	    *.cpp) $(AVR_CXX) $(AVR_CXXFLAGS) -c $$src -o $$obj ;; \
	    *.S)   $(AVR_CC) $(AVR_FLAGS) -x assembler-with-cpp -c $$src -o $$obj ;; \
	    *)     $(AVR_CC) $(AVR_FLAGS) -std=gnu11 -c $$src -o $$obj ;; \
	  esac; done
	avr-ar rcs $@ $(FIRMWARE_BUILD)/core/*.o

# The sketch is compiled as the Arduino IDE would: Arduino.h first, then the .ino as C++.
$(FIRMWARE_ELF): $(FIRMWARE_SRC)/motorid_bench.ino $(FIRMWARE_SRC)/config.h \
                 $(FIRMWARE_SRC)/sine_table.h $(FIRMWARE_BUILD)/core.a
	mkdir -p $(FIRMWARE_BUILD)
	$(AVR_CXX) $(AVR_CXXFLAGS) $(FIRMWARE_DEFS) -I$(FIRMWARE_SRC) -include Arduino.h \
	  -x c++ -c $(FIRMWARE_SRC)/motorid_bench.ino -o $(FIRMWARE_BUILD)/motorid_bench.o
	$(AVR_CC) -mmcu=atmega328p -Os -Wl,--gc-sections -o $@ \
	  $(FIRMWARE_BUILD)/motorid_bench.o $(FIRMWARE_BUILD)/core.a -lm
	avr-size -C --mcu=atmega328p $@

$(FIRMWARE_BUILD)/motorid_bench.hex: $(FIRMWARE_ELF)
	avr-objcopy -O ihex -R .eeprom $< $@

$(SIM_BIN): hardware/sim/motorid_avr_sim.c
	mkdir -p $(SIM_BUILD)
	cc -O2 -Wall -std=gnu11 $$(pkg-config --cflags simavr) $< -o $@ \
	  $$(pkg-config --libs simavr) -lelf -lutil -lm

test test-realtime: firmware avr-sim
