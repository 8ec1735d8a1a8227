/* A minimal test harness for the native firmware tests: CHECK counts failures and
 * prints where; each test file registers its cases with run_*(). */
#ifndef PUMP_TEST_CHECK_H
#define PUMP_TEST_CHECK_H

#include <stdio.h>

extern int g_checks, g_failures;

#define CHECK(cond) do { g_checks++; if (!(cond)) { g_failures++; \
    fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); } } while (0)
#define CHECK_MSG(cond, ...) do { g_checks++; if (!(cond)) { g_failures++; \
    fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond); \
    fprintf(stderr, __VA_ARGS__); fprintf(stderr, "\n"); } } while (0)

void run_codec(const char *vectors_path);
void run_session();
void run_board();
void run_period();

#endif
