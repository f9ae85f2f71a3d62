/*
 * main.c - start-up and the main loop of the ADK board firmware (ATmega2560 @ 16 MHz).
 *
 * .init3 (before the C runtime clears RAM): read MCUSR for the reset cause, clear it and turn the
 * watchdog off (a watchdog reset leaves it running at its shortest timeout), start the start-up
 * stopwatch. .init5: paint the free RAM for the stack's high-water mark. main(): configuration and calibrations from EEPROM, this boot's id (the EEPROM boot
 * counter moved on), clock, UART, ADC, pulse outputs,
 * watchdog; then the loop: check in with the watchdog, do what is due, sleep until the next interrupt.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "adc.h"
#include "app.h"
#include "clock.h"
#include "port.h"
#include "pulses.h"
#include "storage.h"
#include "uart.h"
#include "watchdog.h"

#define STACK_PAINT 0xC5

static uint8_t mcusr_at_reset __attribute__((section(".noinit")));

/* .init5 (after the C runtime has set up the variables, before main: nothing is on the stack yet): paint
 * the free RAM between the end of the variables and the top of the stack with STACK_PAINT, so the
 * stack's deepest reach can be read later (a test reads it in the simulator; on a bench, read it with a
 * debugger). Not earlier: the paint takes ~1.4 ms, and before .init3 has started the start-up stopwatch
 * it made the board's uptime count from 1.4 ms after the reset (clock.h), late by more than the wire's
 * millisecond (a conformance check of when a Disarm reached the pins saw it). */
void stack_paint(void) __attribute__((naked, used, section(".init5")));
void stack_paint(void)
{
    __asm__ volatile("    ldi r30, lo8(_end)\n"
                     "    ldi r31, hi8(_end)\n"
                     "    ldi r24, %0\n"
                     "    ldi r25, hi8(__stack)\n"
                     "    rjmp 2f\n"
                     "1:  st Z+, r24\n"
                     "2:  cpi r30, lo8(__stack)\n"
                     "    cpc r31, r25\n"
                     "    brlo 1b\n"
                     "    breq 1b\n" ::"M"(STACK_PAINT));
}

void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
    mcusr_at_reset = watchdog_early();
    clock_early();
}

static uint8_t reset_cause(uint8_t mcusr)
{
    if (mcusr & _BV(WDRF))
        return RESET_CAUSE_WATCHDOG;
    if (mcusr & _BV(BORF))
        return RESET_CAUSE_BROWN_OUT;
    if (mcusr & _BV(EXTRF))
        return RESET_CAUSE_EXTERNAL;
    if (mcusr & _BV(PORF))
        return RESET_CAUSE_POWER_ON;
    return RESET_CAUSE_SOFTWARE; /* no flag: a jump to the reset vector */
}

void tick_hook(uint32_t now_ms)
{
    watchdog_on_tick(now_ms);
    app_tick(now_ms);
    adc_start_round();
}

int main(void)
{
    uint8_t problem;
    config_status_t config = storage_load_config(&board.cfg, &problem);
    storage_load_calibrations(board.cfg.n_units);
    board.boot_id = storage_new_boot_id(board.cfg.serial); /* before anything is sent */
    /* The ADC's start-up conversions (~0.9 ms, busy-waiting) before the tick starts: from clock_init to
     * sei() a tick is held, and one that fell due twice meanwhile would count once, the uptime a
     * millisecond behind the reset for good (the window was 1.2 ms). What stays in between is short
     * (~0.3 ms): the USB host's init needs the clock, and the pulse outputs take Timer5 from it. */
    adc_init(&board.power);
    clock_init();
    port_init(&board.cfg); /* UART0 and/or the USB host, as configured */
    pulses_init(board.cfg.frame_rate_hz, (uint8_t)(2u * board.cfg.n_units), board.cfg.ppm);
    sei();
    app_boot(reset_cause(mcusr_at_reset), config, problem);
    watchdog_start(board.cfg.mcu_watchdog_ms);
    set_sleep_mode(SLEEP_MODE_IDLE);
    for (;;) {
        watchdog_checkin();
        if (watchdog_selftest_pressed())
            for (;;) /* watchdog self-test: the main loop stops here; interrupts and timers run on */
                ;
        uint8_t busy = app_poll(clock_ms());
        cli();
        if (!busy && !clock_ticked()) {
            sleep_enable();
            sei();
            sleep_cpu(); /* any interrupt wakes the loop: a received byte, the tick, a frame */
            sleep_disable();
        }
        sei();
    }
}
