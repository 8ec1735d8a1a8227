/* The board under test: PumpBoard over FakeHal, and a host that frames commands
 * with the session's epoch and reads the board's lines back (every one must decode
 * with its CRC from epoch 0 and fit 192 bytes). Shared by test_board.cpp and the
 * fuzzer. */
#ifndef PUMP_TEST_RIG_H
#define PUMP_TEST_RIG_H

#include <stdio.h>
#include <string.h>

#include <string>
#include <vector>

#include "fake_hal.h"
#include "pump.h"

struct Rig {
    explicit Rig(uint8_t *eeprom, uint8_t *noinit = NULL) : hal(eeprom, noinit), seq(1), epoch(0), rd(0), bad_lines(0) { board.begin(&hal); }

    /* ms of simulated time in 100 us steps: the plant moves, the board polls */
    void run(uint32_t ms) {
        for (uint32_t i = 0; i < ms * 10; i++) {
            hal.step_plant(100);
            board.poll();
        }
    }
    /* run() with a live host: a PING every 200 ms keeps the watchdog fed */
    void run_live(uint32_t ms) {
        while (ms > 0) {
            uint32_t d = ms < 200 ? ms : 200;
            run(d);
            ms -= d;
            cmd("PING");
        }
    }
    std::string frame(const std::string &body, uint32_t ep) {
        char crc[16];
        bool h = ab_is_hello(body.data(), body.size());
        snprintf(crc, sizeof crc, "*%08X\n", (unsigned)ab_crc32((const uint8_t *)body.data(), body.size(), h ? 0 : ep));
        return body + crc;
    }
    /* Sends "seq verb..." in the current epoch, runs 3 ms -> the answer without the
     * board's seq and the command's ("OK 31", "ER 6 RANGE 1"), "" when none came. */
    std::string cmd(const std::string &text) {
        uint16_t s = seq++;
        lines();   /* what came before is not this command's answer */
        hal.push(frame(std::to_string(s) + " " + text, epoch));
        run(3);
        std::vector<std::string> got = lines();
        for (size_t i = 0; i < got.size(); i++) {
            std::string tag = " " + std::to_string(s) + " ";
            size_t sp = got[i].find(' ');
            std::string rest = got[i].substr(sp + 1);
            if ((rest.compare(0, 3, "OK ") == 0 || rest.compare(0, 3, "ER ") == 0) &&
                rest.compare(2, tag.size(), tag) == 0)
                return rest.substr(0, 2) + rest.substr(2 + tag.size() - 1);
        }
        return "";
    }
    std::string hello(uint32_t ep, int sid = 4242) {
        epoch = ep;
        return cmd("HELLO 2 " + std::to_string(sid) + " " + std::to_string(ep));
    }
    /* The board lines written since the last call, bodies without the CRC. */
    std::vector<std::string> lines() {
        std::vector<std::string> out;
        size_t nl;
        while ((nl = hal.tx.find('\n', rd)) != std::string::npos) {
            std::string l = hal.tx.substr(rd, nl + 1 - rd);
            rd = nl + 1;
            all.push_back(l);
            if (l == "\n") continue;   /* the lone LF before BOOT */
            AbLine d;
            if (l.size() > AB_MAX_BOARD_LINE || ab_decode((const uint8_t *)l.data(), l.size(), AB_MAX_BOARD_LINE, 0, &d)) {
                bad_lines++;
                continue;
            }
            out.push_back(l.substr(0, l.size() - 10));
            log.push_back(out.back());
        }
        return out;
    }
    /* Whether any line seen so far (its body after the board seq) starts with what. */
    bool seen(const std::string &what) {
        lines();
        for (size_t i = 0; i < log.size(); i++) {
            std::string rest = log[i].substr(log[i].find(' ') + 1);
            if (rest.compare(0, what.size(), what) == 0) return true;
            /* events carry the board ms: "EV <ms> KIND ..." */
            if (rest.compare(0, 3, "EV ") == 0) {
                std::string ev = rest.substr(rest.find(' ', 3) + 1);
                if (what.compare(0, 3, "EV ") == 0 && ev.compare(0, what.size() - 3, what.substr(3)) == 0) return true;
            }
        }
        return false;
    }
    void forget() { lines(); log.clear(); }

    FakeHal hal;
    PumpBoard board;
    uint16_t seq;
    uint32_t epoch;
    size_t rd;
    int bad_lines;
    std::vector<std::string> log, all;
};

#endif
