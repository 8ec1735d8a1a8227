/* Fuzz target for the line path of the pump board (and the board's Modbus register
 * accessors behind modbus.cpp's parser). libFuzzer's entry point; fuzz_main.cpp
 * drives it where clang is not installed.
 *
 * The first input byte picks what the rest is:
 *   0: raw UART bytes into the board (framing, e-stop, LONG, CRC: the receive path);
 *   1: line bodies split at LF, each framed with the CRC of the board's current epoch
 *      (HELLO: 0), so the grammar, the argument checks, the session rules and the
 *      verbs are reached (the CRC would stop nearly every mutated line otherwise);
 *   2: one Modbus frame (its CRC appended) through mb_handle to the accessors.
 * Each run: a fresh board over the fake HAL with an open session, the input, 30 ms of
 * simulated time. Invariants, checked by abort(): every board line decodes with its
 * CRC from epoch 0 and fits 192 bytes; every duty is within +-1000 and zero while a
 * latch holds or before a session; the decoder never reads past its input (ASan);
 * the board still answers a PING at its expected seq in the line protocol.
 */
#include <stdlib.h>
#include <string.h>

#include "fuzz_stats.h"
#include "modbus.h"
#include "rig.h"

FuzzStats g_fuzz_stats;

static void require(bool ok, const char *what) {
    if (!ok) {
        fprintf(stderr, "fuzz invariant broken: %s\n", what);
        abort();
    }
}

static void count_answers(Rig &r) {
    r.lines();
    for (size_t i = 0; i < r.log.size(); i++) {
        const std::string &l = r.log[i];
        size_t sp = l.find(' ');
        std::string rest = l.substr(sp + 1);
        if (rest.compare(0, 3, "OK ") == 0) g_fuzz_stats.ok++;
        else if (rest.compare(0, 3, "ER ") == 0) {
            size_t a = rest.find(' ', 3);
            int code = atoi(rest.c_str() + a + 1);
            if (code > 0 && code < AB_N_ERRORS) g_fuzz_stats.errors[code]++;
        } else if (rest.compare(0, 3, "EV ") == 0) g_fuzz_stats.events++;
    }
}

static void check_outputs(Rig &r) {
    uint8_t st = r.board.link.state;
    bool latched = st == ST_ESTOP || st == ST_WDOG || st == ST_FAULT;
    for (int k = 0; k < N_JOINTS; k++) {
        require(r.hal.duty[k] >= -1000 && r.hal.duty[k] <= 1000, "duty within +-1000");
        if (latched || !r.board.link.outputs_allowed) require(r.hal.duty[k] == 0, "no drive while latched");
    }
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static uint8_t ee[EE_SIZE];
    if (size < 1 || size > 4096) return 0;
    memset(ee, 0xFF, sizeof ee);
    Rig r(ee);
    r.hello(1);
    uint8_t mode = data[0] % 3;
    std::string in((const char *)data + 1, size - 1);
    if (mode == 0) {
        for (size_t i = 0; i < in.size(); i += 48) {   /* as the UART delivers it, between passes */
            r.hal.push(in.substr(i, 48));
            r.run(1);
        }
    } else if (mode == 1) {
        size_t start = 0;
        while (start <= in.size()) {
            size_t nl = in.find('\n', start);
            if (nl == std::string::npos) nl = in.size();
            std::string body = in.substr(start, nl - start);
            if (body.size() <= 86) {
                r.hal.push(r.frame(body, r.board.link.sess.epoch));
                r.run(1);
            }
            start = nl + 1;
        }
    } else {
        static uint8_t out[MB_FRAME_MAX];
        uint8_t frame[MB_FRAME_MAX];
        size_t n = in.size() > MB_FRAME_MAX - 2 ? MB_FRAME_MAX - 2 : in.size();
        memcpy(frame, in.data(), n);
        if (n > 0) frame[0] = mb_address();
        uint16_t crc = mb_crc16(frame, (uint16_t)n);
        frame[n] = (uint8_t)(crc & 0xFF);
        frame[n + 1] = (uint8_t)(crc >> 8);
        int got = mb_handle(frame, (uint16_t)(n + 2), out, sizeof out);
        require(got >= 0 && got <= MB_FRAME_MAX, "Modbus reply within its buffer");
        if (got >= 5) require(mb_crc16(out, (uint16_t)got) == 0, "Modbus reply CRC");
        g_fuzz_stats.modbus++;
    }
    r.run(30);
    check_outputs(r);
    require(r.bad_lines == 0, "every board line decodes and fits 192 bytes");
    if (!r.board.link.modbus() && r.board.link.sess.open()) {
        r.hal.push("\n");   /* ends a line the input left unfinished, as a host's retry would */
        r.run(1);
        r.seq = (uint16_t)r.board.link.sess.expect;
        r.epoch = r.board.link.sess.epoch;
        std::string a = r.cmd("PING");
        require(a.compare(0, 3, "OK ") == 0, "the board still answers PING");
    }
    count_answers(r);
    g_fuzz_stats.runs++;
    return 0;
}
