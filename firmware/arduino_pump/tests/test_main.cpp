/* The native firmware tests: codec against the shared vectors, session rules, the
 * board over the fake HAL. usage: test VECTORS.txt (tools/vectors2txt.py's output) */
#include <stdio.h>

#include "check.h"

int g_checks = 0, g_failures = 0;

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: %s vectors.txt\n", argv[0]);
        return 2;
    }
    run_codec(argv[1]);
    run_session();
    run_board();
    run_period();
    printf("%d checks, %d failed\n", g_checks, g_failures);
    return g_failures ? 1 : 0;
}
