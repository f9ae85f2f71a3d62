/*
 * clock.h - the board's time: a 1 kHz tick from Timer0 counting milliseconds since reset (uptime, as in
 * Telemetry.time_ms), started so that it counts from the reset itself, not from the end of start-up.
 *
 * clock_early() runs in .init3 (before the C runtime clears RAM): it starts Timer5 free-running as a
 * stopwatch. clock_init() reads how long start-up took from it and starts the 1 kHz tick at that
 * uptime, so the board's clock agrees with the reset instant to within Timer5's 64 us resolution.
 */
#ifndef CLOCK_H
#define CLOCK_H

#include <avr/io.h>
#include <stdint.h>

/* .init3: start Timer5 free-running at F_CPU/1024 (64 us ticks, 4.2 s to wrap) as the start-up
 * stopwatch. Inline: it runs in a naked .init function, before the C runtime. */
static inline __attribute__((always_inline)) void clock_early(void)
{
    TCCR5A = 0;
    TCNT5 = 0;
    TCCR5B = _BV(CS52) | _BV(CS50);
}

void clock_init(void);
/* Milliseconds since reset (wraps after 49.7 days). */
uint32_t clock_ms(void);
/* Microseconds since reset (4 us resolution: Timer0's count within the millisecond; wraps after 71.6
 * minutes). For timeouts shorter than a millisecond (the USB host stack's transactions). */
uint32_t clock_us(void);
/* Ticks seen by the main loop: 1 if at least one tick happened since the last call. */
uint8_t clock_ticked(void);
/* Called from the tick interrupt with the new uptime (main.c: the watchdog window, ADC sampling). */
void tick_hook(uint32_t now_ms);

#endif /* CLOCK_H */
