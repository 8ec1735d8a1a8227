/* The stand-in sketch's "board" for the emulator (read by simavr_runner.read_config_h
 * as the pump board's config.h is): motor 1 on EN 9 / IN 22, 23 (sketch.cpp drives
 * it), end stops 30/31 (it reads them); motors 2, 3 are wired but never driven. */
#define N_JOINTS 3
#define PERIOD_MS 10
#define LIM_MIN_MRAD {0, 0, 0}
#define LIM_MAX_MRAD {524, 960, 1047}
#define BEND_DEFAULT {{205, 0, 716, 1047}, {205, 0, 716, 1047}, {205, 0, 716, 1047}}
#define PIN_EN {9, 10, 11}
#define PIN_IN1 {22, 24, 26}
#define PIN_IN2 {23, 25, 27}
#define PIN_BEND {0, 1, 2}
#define PIN_STOP_RET {30, 32, 34}
#define PIN_STOP_EXT {31, 33, 35}
