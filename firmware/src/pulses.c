/* pulses.c - servo pulse and PPM-sum generation (see pulses.h). */
#include "pulses.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <math.h>
#include <util/atomic.h>

#include "board_pins.h"
#include "protocol_gen.h"

#define TICKS_PER_US 2u /* F_CPU / 8 */
#define PPM_CHANNELS 8u
#define PPM_FRAME_US 22500u
#define PPM_MARK_US 300u
#define PPM_MIN_US 700u
#define PPM_MAX_US 2300u

typedef struct {
    volatile uint16_t *ocr;
    volatile uint8_t *tccra;
    uint8_t com; /* COMnx1: non-inverting (set at BOTTOM, clear on match) */
    volatile uint8_t *ddr;
    uint8_t bit;
} channel_t;

static const channel_t CHANNELS[PULSE_CHANNELS_HW] PROGMEM = {
    {&OCR1A, &TCCR1A, _BV(COM1A1), &DDRB, 5}, {&OCR1B, &TCCR1A, _BV(COM1B1), &DDRB, 6},
    {&OCR1C, &TCCR1A, _BV(COM1C1), &DDRB, 7}, {&OCR3A, &TCCR3A, _BV(COM3A1), &DDRE, 3},
    {&OCR3B, &TCCR3A, _BV(COM3B1), &DDRE, 4}, {&OCR3C, &TCCR3A, _BV(COM3C1), &DDRE, 5},
    {&OCR4A, &TCCR4A, _BV(COM4A1), &DDRH, 3}, {&OCR4B, &TCCR4A, _BV(COM4B1), &DDRH, 4},
    {&OCR4C, &TCCR4A, _BV(COM4C1), &DDRH, 5}, {&OCR5A, &TCCR5A, _BV(COM5A1), &DDRL, 3},
    {&OCR5B, &TCCR5A, _BV(COM5B1), &DDRL, 4}, {&OCR5C, &TCCR5A, _BV(COM5C1), &DDRL, 5},
};

/* Each channel's fine width (1/512 us: whole ticks << 8 | 256ths of a tick) and the fraction of a tick
 * carried to the next frame. The frame-start interrupt writes each channel's dithered ticks for the next
 * frame; a new width is also written at once (output), so it takes effect at the next frame's start (the
 * hardware double-buffers OCRnx until BOTTOM; the simavr harness models that, firmware/harness/ocr.c). */
static volatile uint16_t ticks[PULSE_CHANNELS_HW]; /* fine >> 8: whole ticks (0: no pulse) */
static volatile uint8_t fraction[PULSE_CHANNELS_HW]; /* fine & 0xFF: 256ths of a tick */
static uint8_t residue[PULSE_CHANNELS_HW];
static uint8_t before[PULSE_CHANNELS_HW]; /* residue as it was before the frame-start interrupt's last carry */
static uint16_t top;
static uint8_t channels, ppm_on;
static volatile uint8_t frame_flag;
static volatile uint16_t ppm_ticks[PPM_CHANNELS + 1]; /* periods of the next PPM frame: channels, sync */
static volatile uint8_t ppm_slot, ppm_count;

static volatile uint16_t held; /* channels pulses_set leaves alone (pulses_hold) */

/* Channel `ch` to `width_fine` (its pin connected or not, its ticks and fraction for the frame-start
 * interrupt, its PPM slot); with interrupts off. */
static void output(uint8_t ch, uint32_t width_fine)
{
    channel_t cc;
    memcpy_P(&cc, &CHANNELS[ch], sizeof cc);
    const channel_t *c = &cc;
    uint16_t whole = (uint16_t)(width_fine >> PULSE_FRACTION_BITS);
    if (!whole) {
        *c->tccra &= (uint8_t)~c->com; /* disconnected: the pin stays low */
    } else {
        /* OCRnx is double-buffered in fast-PWM mode: written now, it takes effect at the next frame's
         * start; the frame-start interrupt then writes each following frame's. Left to the interrupt
         * alone, a change would wait a frame longer. The next frame is dithered too: its carry taken again
         * from the residue the interrupt started it with, with the new fraction. (Written undithered, the
         * fraction was lost on every frame a new width arrived in: with a setpoint each frame, as a 50 Hz
         * host sends at 50 Hz frames, widths were truncated to whole ticks — a gimbal held just past its
         * servo's dead zone never moved, and the host's loop wound up against it.) */
        uint16_t sum = (uint16_t)(before[ch] + (uint8_t)width_fine);
        residue[ch] = (uint8_t)sum;
        *c->ocr = (uint16_t)(whole + (sum >> 8) - 1u);
        if (!ticks[ch])
            *c->tccra |= c->com; /* a channel coming on (boot, a calibration stored) */
    }
    ticks[ch] = whole;
    fraction[ch] = (uint8_t)width_fine;
    if (ppm_on && ch < PPM_CHANNELS) {
        /* the PPM stage clamps to its channel range; a channel without pulses sends its minimum */
        uint16_t width_us = pulses_reported_us(width_fine);
        uint16_t w = width_us < PPM_MIN_US ? PPM_MIN_US : (width_us > PPM_MAX_US ? PPM_MAX_US : width_us);
        uint16_t sum = 0;
        ppm_ticks[ch] = (uint16_t)(w * TICKS_PER_US);
        for (uint8_t i = 0; i < ppm_count; i++)
            sum = (uint16_t)(sum + ppm_ticks[i] / TICKS_PER_US);
        ppm_ticks[ppm_count] = (uint16_t)((PPM_FRAME_US - sum) * TICKS_PER_US);
    }
}

void pulses_set(uint8_t ch, uint32_t width_fine)
{
    if (ch >= channels)
        return;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        if (!(held & (1u << ch)))
            output(ch, width_fine);
    }
}

void pulses_hold(uint16_t mask, uint16_t width_us)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        for (uint8_t ch = 0; ch < channels; ch++)
            if (mask & (1u << ch))
                output(ch, (uint32_t)width_us * PULSE_FINE_PER_US);
        held |= mask;
    }
}

void pulses_release(uint16_t mask)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { held &= (uint16_t)~mask; }
}

uint32_t pulses_get(uint8_t ch)
{
    uint32_t w = 0;
    if (ch < channels)
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { w = ((uint32_t)ticks[ch] << PULSE_FRACTION_BITS) | fraction[ch]; }
    return w;
}

uint16_t pulses_reported_us(uint32_t width_fine) { return (uint16_t)((width_fine + 256u) >> 9); }

float pulses_period_s(void) { return (float)(top + 1u) / (TICKS_PER_US * 1e6f); }

uint32_t pulses_longest_fine(void) { return (uint32_t)(top + 1u - PULSE_GAP_TICKS) << PULSE_FRACTION_BITS; }

uint8_t pulses_frame_started(void)
{
    uint8_t f;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        f = frame_flag;
        frame_flag = 0;
    }
    return f;
}

/* Frame start (every timer is at BOTTOM within a few cycles of Timer1): each channel's whole ticks for
 * the next frame (OCRnx is double-buffered until BOTTOM), its fraction of a tick carried on (first-order
 * sigma-delta), so the widths of n frames add up to n fine widths within one tick. Runs on when the main loop hangs. ~45 cycles a channel,
 * ~35 us for twelve: interrupts stay enabled (ISR_NOBLOCK) so that a byte arriving at 1 Mbaud (one every
 * 10 us, the UART holds three) is never lost behind it. Nothing else touches these arrays or timers
 * 1/3/4's registers from an interrupt (Timer5's PPM interrupt only runs when Timer5 drives no channel). */
ISR(TIMER1_OVF_vect, ISR_NOBLOCK)
{
    frame_flag = 1;
    for (uint8_t ch = 0; ch < channels; ch++) {
        uint16_t whole = ticks[ch];
        if (!whole)
            continue;
        uint16_t sum = (uint16_t)(residue[ch] + fraction[ch]);
        before[ch] = residue[ch];
        residue[ch] = (uint8_t)sum;
        volatile uint16_t *ocr = (volatile uint16_t *)pgm_read_ptr(&CHANNELS[ch].ocr);
        *ocr = (uint16_t)(whole + (sum >> 8) - 1u);
    }
}

ISR(TIMER5_OVF_vect)
{
    /* Period k+1 was loaded at this BOTTOM; what is written now runs in period k+2. */
    uint8_t next = (uint8_t)((ppm_slot + 2u) % (ppm_count + 1u));
    OCR5A = (uint16_t)(ppm_ticks[next] - 1u);
    ppm_slot = (uint8_t)((ppm_slot + 1u) % (ppm_count + 1u));
}

static void start_ppm(void)
{
    ppm_count = channels < PPM_CHANNELS ? channels : PPM_CHANNELS;
    for (uint8_t i = 0; i < ppm_count; i++)
        ppm_ticks[i] = PPM_MIN_US * TICKS_PER_US;
    ppm_ticks[ppm_count] = (uint16_t)((PPM_FRAME_US - ppm_count * PPM_MIN_US) * TICKS_PER_US);
    DDRL |= _BV(4);
    TCCR5A = _BV(COM5B1) | _BV(WGM51) | _BV(WGM50); /* fast PWM, TOP = OCR5A */
    OCR5B = PPM_MARK_US * TICKS_PER_US - 1u;
    OCR5A = (uint16_t)(ppm_ticks[0] - 1u);
    TCNT5 = 0;
    ppm_slot = 0;
    TIMSK5 = _BV(TOIE5);
}

void pulses_init(float frame_rate_hz, uint8_t n_channels, uint8_t ppm)
{
    channels = n_channels > PULSE_CHANNELS_HW ? PULSE_CHANNELS_HW : n_channels;
    top = (uint16_t)(lrintf(1e6f * TICKS_PER_US / frame_rate_hz) - 1);
    ppm_on = ppm && channels <= 9u; /* Timer5 must be free */
    uint8_t timers = (uint8_t)((channels + 2u) / 3u);
    volatile uint16_t *const icr[4] = {&ICR1, &ICR3, &ICR4, &ICR5};
    volatile uint16_t *const tcnt[4] = {&TCNT1, &TCNT3, &TCNT4, &TCNT5};
    volatile uint8_t *const tccra[4] = {&TCCR1A, &TCCR3A, &TCCR4A, &TCCR5A};
    for (uint8_t t = 0; t < timers; t++) {
        *tccra[t] = _BV(WGM11); /* fast PWM mode 14 (WGMn1 in A, WGMn3:2 in B); outputs connected below */
        *icr[t] = top;
        *tcnt[t] = 0;
    }
    for (uint8_t ch = 0; ch < channels; ch++) {
        channel_t c;
        memcpy_P(&c, &CHANNELS[ch], sizeof c);
        *c.ddr |= _BV(c.bit);
    }
    if (ppm_on)
        start_ppm();
    /* Start every timer in one burst: their frames begin within a few cycles of each other. */
    const uint8_t mode14 = _BV(WGM13) | _BV(WGM12) | _BV(CS11);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        if (timers > 0)
            TCCR1B = mode14;
        if (timers > 1)
            TCCR3B = mode14;
        if (timers > 2)
            TCCR4B = mode14;
        if (timers > 3)
            TCCR5B = mode14;
        else if (ppm_on)
            TCCR5B = _BV(WGM53) | _BV(WGM52) | _BV(CS51);
        TIMSK1 = _BV(TOIE1);
    }
}
