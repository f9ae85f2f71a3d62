/* clock.c - the 1 kHz tick (see clock.h). */
#include "clock.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#define TICKS_PER_MS (F_CPU / 64UL / 1000UL)               /* Timer0 at F_CPU/64: 250 per ms */
#define STOPWATCH_US_PER_TICK (1024UL * 1000000UL / F_CPU) /* Timer5 at F_CPU/1024: 64 us */

static volatile uint32_t ms;
static volatile uint8_t ticked;

void clock_init(void)
{
    /* Timer0 is started first and the stopwatch read beside its count: the millisecond's phase, worked
     * out from the stopwatch (32-bit divisions, ~0.1 ms), is then moved on by the counts that passed
     * meanwhile, and set while the timer runs. A count preset before the clock is selected is lost in
     * simavr (it restarts a timer's count then): the tick ran up to a millisecond behind the reset, by how
     * long start-up happened to take (tests/test_firmware_board.py saw it when the CRC got faster). */
    TCCR0A = _BV(WGM01); /* CTC, TOP = OCR0A */
    OCR0A = (uint8_t)(TICKS_PER_MS - 1u);
    TCCR0B = _BV(CS01) | _BV(CS00); /* /64 */
    uint8_t started = TCNT0;
    uint32_t us = (uint32_t)TCNT5 * STOPWATCH_US_PER_TICK;
    TCCR5B = 0; /* the stopwatch is done: Timer5 goes to the pulse outputs */
    uint32_t now_ms = us / 1000UL;
    uint16_t phase = (uint16_t)((us % 1000UL) * TICKS_PER_MS / 1000UL);
    phase = (uint16_t)(phase + (uint8_t)(TCNT0 - started));
    if (phase >= TICKS_PER_MS) {
        phase = (uint16_t)(phase - TICKS_PER_MS);
        now_ms++;
    }
    /* A write to TCNT0 blocks a compare match on the next timer clock (the datasheet's "Compare Match
     * Blocking by TCNT0 Write"): a count written equal to OCR0A would miss its match, and the counter
     * would run on through 255 and round to it again, the tick 1.024 ms late for good. That count's match
     * is due within 4 us: its millisecond is counted here (its hooks are skipped: interrupts are still
     * off, and a watchdog check-in, a link check and an ADC round come again a millisecond later), and
     * the count starts from the 0 the match would have set. */
    if (phase == TICKS_PER_MS - 1u) {
        phase = 0;
        now_ms++;
    }
    TCNT0 = (uint8_t)phase;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { ms = now_ms; }
    TIMSK0 = _BV(OCIE0A);
}

ISR(TIMER0_COMPA_vect)
{
    uint32_t now = ++ms;
    ticked = 1;
    tick_hook(now);
}

uint32_t clock_ms(void)
{
    uint32_t now;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { now = ms; }
    return now;
}

uint32_t clock_us(void)
{
    uint32_t m;
    uint8_t t, pending;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        m = ms;
        t = TCNT0;
        pending = (TIFR0 & _BV(OCF0A)) != 0; /* the counter wrapped and the tick is not counted yet */
        if (pending && t < TICKS_PER_MS / 2u)
            m++; /* read after the wrap: this count belongs to the next millisecond */
    }
    return m * 1000UL + (uint32_t)t * (1000UL / TICKS_PER_MS);
}

uint8_t clock_ticked(void)
{
    uint8_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        t = ticked;
        ticked = 0;
    }
    return t;
}
