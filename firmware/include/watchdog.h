/*
 * watchdog.h - the MCU watchdog: the AVR's hardware watchdog behind a configurable timeout.
 *
 * The hardware watchdog's timeouts come in fixed steps (16 ms .. 8 s, 0.5 s being 0.512 s on a real
 * part), so the board runs it at its shortest step (16 ms, system-reset mode) and lets the 1 kHz tick
 * interrupt restart it only while the main loop has checked in within the last
 * (timeout - 16 ms). When the main loop stops, the tick stops restarting it and the hardware resets
 * the MCU `timeout` after the main loop's last check-in, to the millisecond; if the tick itself dies
 * (interrupts off, a runaway), the hardware resets within 16 ms. Either way the reset sets WDRF and the
 * next HelloReply reports ResetCause WATCHDOG. Timeouts under 32 ms use the hardware step directly.
 *
 * The watchdog self-test input (board_pins.h) lets a bench prove all of this on a real board.
 */
#ifndef WATCHDOG_H
#define WATCHDOG_H

#include <avr/io.h>
#include <avr/wdt.h>
#include <stdint.h>

#define WATCHDOG_HW_MS 16u

/* .init3: read and clear MCUSR, turn the watchdog off (a watchdog reset leaves it running at 16 ms, and
 * WDRF set keeps it on until cleared). Inline: it runs in a naked .init function, before the C runtime. */
static inline __attribute__((always_inline)) uint8_t watchdog_early(void)
{
    uint8_t cause = MCUSR;
    MCUSR = 0;
    wdt_disable();
    return cause;
}

void watchdog_start(uint16_t timeout_ms);
/* From the tick interrupt: restart the hardware watchdog if the main loop checked in recently. */
void watchdog_on_tick(uint32_t now_ms);
/* The main loop is alive (call once per loop iteration). */
void watchdog_checkin(void);
/* Poll the self-test input: 1 when it went from high to low since the last call after boot. */
uint8_t watchdog_selftest_pressed(void);

#endif /* WATCHDOG_H */
