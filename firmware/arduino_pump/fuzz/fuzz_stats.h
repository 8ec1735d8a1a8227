/* What the fuzz runs saw (the fallback driver prints it; libFuzzer ignores it). */
#ifndef PUMP_FUZZ_STATS_H
#define PUMP_FUZZ_STATS_H

#include <stdint.h>

#include "protodef.h"

struct FuzzStats {
    uint64_t runs, ok, events, modbus;
    uint64_t errors[AB_N_ERRORS];
};

extern FuzzStats g_fuzz_stats;

#endif
