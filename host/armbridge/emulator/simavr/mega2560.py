"""The ATmega2560 as the Arduino Mega wires it: pins, ports, PWM timers; and a small ELF reader.

Data from the Debian Arduino core's `variants/mega/pins_arduino.h` and the
ATmega2560 datasheet (register summary), for the simavr harness: which data
addresses to watch for a pin, and how to turn those bytes into what the pin
does. simavr's mega2560 model fires no PWM IRQs for the phase-correct PWM the
Arduino core sets up on timers 1-5, so a PWM pin's duty is read from its
OCRnx register while its COMnx1 bit in TCCRnA connects it (toolchain notes,
pitfall 2); with the bit clear the pin is a plain output (analogWrite(0) and
analogWrite(255) use digitalWrite).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

# Arduino pin -> (port, bit), pins 0..69 (pins_arduino.h: digital_pin_to_port/bit_mask).
_PORTS = "EEEEGEHHHHBBBBJJHHDDDDAAAAAAAACCCCCCCCDGGGLLLLLLLLBBBBFFFFFFFFKKKKKKKK"
_BITS = (0, 1, 4, 5, 5, 3, 3, 4, 5, 6, 4, 5, 6, 7, 1, 0, 1, 0, 3, 2, 1, 0,
         0, 1, 2, 3, 4, 5, 6, 7, 7, 6, 5, 4, 3, 2, 1, 0, 7, 2, 1, 0,
         7, 6, 5, 4, 3, 2, 1, 0, 3, 2, 1, 0, *range(8), *range(8))
# PINx address per port (DDRx = +1, PORTx = +2), data space.
PORT_BASE = {"A": 0x20, "B": 0x23, "C": 0x26, "D": 0x29, "E": 0x2C, "F": 0x2F, "G": 0x32,
             "H": 0x100, "J": 0x103, "K": 0x106, "L": 0x109}
# PWM pin -> timer channel (digital_pin_to_timer).
_PWM = {2: "3B", 3: "3C", 4: "0B", 5: "3A", 6: "4A", 7: "4B", 8: "4C", 9: "2B", 10: "2A", 11: "1A",
        12: "1B", 13: "0A", 44: "5C", 45: "5B", 46: "5A"}
# timer -> (TCCRnA, TCCRnB, ICRn or None, {channel: OCRnx}, 16-bit)
_TIMERS = {
    0: (0x44, 0x45, None, {"A": 0x47, "B": 0x48}, False),
    1: (0x80, 0x81, 0x86, {"A": 0x88, "B": 0x8A, "C": 0x8C}, True),
    2: (0xB0, 0xB1, None, {"A": 0xB3, "B": 0xB4}, False),
    3: (0x90, 0x91, 0x96, {"A": 0x98, "B": 0x9A, "C": 0x9C}, True),
    4: (0xA0, 0xA1, 0xA6, {"A": 0xA8, "B": 0xAA, "C": 0xAC}, True),
    5: (0x120, 0x121, 0x126, {"A": 0x128, "B": 0x12A, "C": 0x12C}, True),
}
_COM1_BIT = {"A": 7, "B": 5, "C": 3}
ADC_PINS = range(54, 70)     # A0..A15
ADCSRA, ADMUX, ADCSRB = 0x7A, 0x7C, 0x7B
ADSC = 6                     # ADCSRA's start-conversion bit
RAM_START = 0x200            # first SRAM byte after the extended I/O space
DATA_VMA = 0x800000          # avr-gcc's offset of the data space in ELF addresses


@dataclass(frozen=True)
class Pin:
    """One Arduino pin: its port and bit, and its PWM channel (None if it has none)."""

    number: int
    port: str
    bit: int
    timer: int | None = None
    channel: str | None = None

    @property
    def ddr(self) -> int:
        return PORT_BASE[self.port] + 1

    @property
    def out(self) -> int:
        return PORT_BASE[self.port] + 2

    @property
    def name(self) -> str:
        """The harness's name of the pin: port letter and bit ("C7")."""
        return f"{self.port}{self.bit}"

    def watch(self) -> list[int]:
        """Data addresses whose bytes decide what this output pin does."""
        addrs = [self.ddr, self.out]
        if self.timer is not None and self.channel is not None:
            tccra, tccrb, icr, ocr, wide = _TIMERS[self.timer]
            addrs += [tccra, tccrb, ocr[self.channel]]
            if wide:
                addrs += [ocr[self.channel] + 1]
                if icr is not None:
                    addrs += [icr, icr + 1]
        return addrs

    def level(self, regs: dict[int, int]) -> int:
        """The pin as a digital output: 1 high, 0 low or not an output."""
        return (regs[self.ddr] >> self.bit) & (regs[self.out] >> self.bit) & 1

    def duty(self, regs: dict[int, int]) -> float:
        """The pin's output duty in [0, 1]: PWM while COMnx1 connects it, else its level."""
        if self.timer is None or self.channel is None:
            return float(self.level(regs))
        tccra, tccrb, icr, ocr, wide = _TIMERS[self.timer]
        if not (regs[tccra] >> _COM1_BIT[self.channel]) & 1 or not (regs[self.ddr] >> self.bit) & 1:
            return float(self.level(regs))
        a = ocr[self.channel]
        value = regs[a] | ((regs[a + 1] << 8) if wide else 0)
        wgm = (regs[tccra] & 3) | (((regs[tccrb] >> 3) & (3 if wide else 1)) << 2)
        top, fast = _top(wgm, wide, regs, icr, ocr)
        if top <= 0:
            return 0.0
        duty = (value + 1) / (top + 1) if fast else value / top
        return min(max(duty, 0.0), 1.0)


def _top(wgm: int, wide: bool, regs: dict[int, int], icr: int | None, ocr: dict[str, int]) -> tuple[int, bool]:
    """(TOP, fast PWM?) of a timer's waveform mode (datasheet tables 16-8, 17-2, 20-8)."""
    ocra = regs.get(ocr["A"], 0) | ((regs.get(ocr["A"] + 1, 0) << 8) if wide else 0)
    icrv = (regs.get(icr, 0) | (regs.get(icr + 1, 0) << 8)) if icr is not None else 0
    if not wide:
        return {1: (255, False), 3: (255, True), 5: (ocra, False), 7: (ocra, True)}.get(wgm, (255, False))
    table = {1: (255, False), 2: (511, False), 3: (1023, False), 5: (255, True), 6: (511, True), 7: (1023, True),
             8: (icrv, False), 9: (ocra, False), 10: (icrv, False), 11: (ocra, False), 14: (icrv, True),
             15: (ocra, True)}
    return table.get(wgm, (255, False))


def pin(number: int) -> Pin:
    """The Arduino Mega pin `number` (0..69; A0 is 54)."""
    if not 0 <= number < len(_PORTS):
        raise ValueError(f"the Arduino Mega has pins 0..{len(_PORTS) - 1}, not {number}")
    ch = _PWM.get(number)
    return Pin(number, _PORTS[number], _BITS[number], int(ch[0]) if ch else None, ch[1] if ch else None)


def adc_channel(number: int) -> int:
    """The ADC channel of an analog pin (A0 = 54 -> 0)."""
    if number not in ADC_PINS:
        raise ValueError(f"pin {number} is not an analog input (A0..A15 are 54..69)")
    return number - ADC_PINS[0]


# ----------------------------------------------------------------- ELF

@dataclass(frozen=True)
class ElfImage:
    """What the emulator's reports need from an AVR .elf: symbols and section sizes."""

    path: Path
    symbols: dict[str, tuple[int, int]]   # name -> (address, size); data symbols without DATA_VMA
    sections: dict[str, int]              # name -> size in bytes
    functions: dict[str, int]             # function symbol -> flash byte address

    def function(self, name: str) -> int | None:
        """The address of function `name`: a C symbol, or a C++ name such as
        "PumpBoard::control" matched in its mangled form (any overload, any LTO clone)."""
        if name in self.functions:
            return self.functions[name]
        needle = "".join(f"{len(part)}{part}" for part in name.split("::"))
        hits = sorted(a for s, a in self.functions.items() if s.startswith("_Z") and needle in s)
        return hits[0] if hits else None

    @property
    def flash_bytes(self) -> int:
        return self.sections.get(".text", 0) + self.sections.get(".data", 0)

    @property
    def static_ram_bytes(self) -> int:
        return sum(self.sections.get(s, 0) for s in (".data", ".bss", ".noinit"))

    @property
    def ram_end_of_statics(self) -> int:
        """First data address after .data/.bss/.noinit (where the heap would start)."""
        for name in ("__heap_start", "_end", "__bss_end"):
            if name in self.symbols:
                return self.symbols[name][0]
        return RAM_START + self.static_ram_bytes


def read_elf(path: str | Path) -> ElfImage:
    """Symbols and section sizes of a 32-bit little-endian ELF (what avr-gcc writes)."""
    p = Path(path)
    data = p.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        raise ValueError(f"{p} is not a 32-bit little-endian ELF file")
    shoff, = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x2E)
    heads = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]

    def name_at(table: int, off: int) -> str:
        start = heads[table][4] + off
        return data[start:data.index(b"\0", start)].decode("latin-1")

    sections: dict[str, int] = {}
    symbols: dict[str, tuple[int, int]] = {}
    functions: dict[str, int] = {}
    for h in heads:
        sname = name_at(shstrndx, h[0])
        sections[sname] = h[5]      # SHT_NOBITS (.bss) has a size too
        if h[1] == 2:          # SHT_SYMTAB
            strtab = h[6]
            for k in range(h[5] // 16):
                st_name, value, size, info, _other, _shndx = struct.unpack_from("<IIIBBH", data, h[4] + k * 16)
                if st_name:
                    sym = name_at(strtab, st_name)
                    symbols[sym] = (value - DATA_VMA if value >= DATA_VMA else value, size)
                    if info & 0xF == 2:     # STT_FUNC
                        functions[sym] = value
    return ElfImage(p, symbols, sections, functions)
