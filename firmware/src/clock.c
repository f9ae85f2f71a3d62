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
    uint32_t us = (uint32_t)TCNT5 * STOPWATCH_US_PER_TICK;
    TCCR5B = 0; /* the stopwatch is done: Timer5 goes to the pulse outputs */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { ms = us / 1000UL; }
    TCCR0A = _BV(WGM01); /* CTC, TOP = OCR0A */
    OCR0A = (uint8_t)(TICKS_PER_MS - 1u);
    TCNT0 = (uint8_t)((us % 1000UL) * TICKS_PER_MS / 1000UL);
    TIMSK0 = _BV(OCIE0A);
    TCCR0B = _BV(CS01) | _BV(CS00); /* /64 */
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
