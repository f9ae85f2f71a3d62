/* watchdog.c - the windowed hardware watchdog and its self-test input (see watchdog.h). */
#include "watchdog.h"

#include <avr/io.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "board_pins.h"
#include "clock.h"

static volatile uint32_t alive_ms;
static volatile uint16_t window_ms; /* restart the hardware only while the loop checked in this recently */
static volatile uint8_t running, direct;
static uint8_t selftest_was_high;

void watchdog_start(uint16_t timeout_ms)
{
    DDRK &= (uint8_t)~_BV(SELFTEST_PIN_BIT); /* self-test input with pull-up */
    PORTK |= _BV(SELFTEST_PIN_BIT);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        alive_ms = clock_ms();
        direct = timeout_ms < 2u * WATCHDOG_HW_MS;
        window_ms = direct ? 0u : (uint16_t)(timeout_ms - WATCHDOG_HW_MS);
        running = 1;
    }
    wdt_enable(WDTO_15MS);
}

void watchdog_checkin(void)
{
    uint32_t now = clock_ms();
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { alive_ms = now; }
    if (direct)
        wdt_reset();
}

void watchdog_on_tick(uint32_t now_ms)
{
    if (running && !direct && now_ms - alive_ms <= window_ms)
        wdt_reset();
}

uint8_t watchdog_selftest_pressed(void)
{
    uint8_t high = (PINK & _BV(SELFTEST_PIN_BIT)) != 0;
    uint8_t pressed = selftest_was_high && !high;
    selftest_was_high = high;
    return pressed;
}
