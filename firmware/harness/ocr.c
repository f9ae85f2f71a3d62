/*
 * ocr.c - the double-buffered output compare registers of the 16-bit timers in fast-PWM modes.
 *
 * On the ATmega2560 (datasheet, 16-bit Timer/Counter: "Fast PWM Mode" and the waveform generation mode
 * table) every PWM mode double-buffers OCRnx: the CPU writes a buffer, which the timer copies into the
 * compare register at BOTTOM (fast PWM). A width written in the middle of a pulse therefore takes effect
 * at the next frame: a pulse is never cut short nor stretched. 16-bit registers are written through the
 * timer's TEMP register: the high byte waits there until the low byte is written, then both go at once.
 *
 * simavr 1.6 has neither: a write takes effect at once. When the firmware lowers a width below the
 * timer's present count while the pin is still high (the failsafe's 1000 us rotor pulse written ~1.3 ms
 * into a 1.6 ms pulse), the compare match is missed and the pin stays high into the next frame: an 11 ms
 * "pulse" that no real board outputs (the intermittent conformance failure of the link-loss failsafe,
 * about one run in 16: the write lands in that window 0.6 ms of every 10 ms frame).
 *
 * The harness models the hardware: it takes over the OCRnxH/OCRnxL writes of the 16-bit timers. While
 * a timer runs in a fast-PWM mode, the high byte goes to the timer's TEMP, and a low-byte write puts the
 * 16-bit value into the buffer; one cycle after the timer's next BOTTOM (simavr's overflow event) the
 * buffered values are handed to simavr's own OCR handler, so the new match lands in the new frame. In
 * every other mode (and with the clock stopped) the write goes through at once, as on the chip.
 * Phase-correct PWM (update at TOP) is not modelled: the firmware does not use it.
 */
#include <string.h>

#include <avr_timer.h>
#include <sim_cycle_timers.h>
#include <sim_io.h>

#include "harness.h"

#define MAX_TIMERS 6

typedef struct {
    avr_io_addr_t lo, hi; /* data-space addresses of OCRnxL and OCRnxH */
    avr_io_write_t write; /* simavr's handler of the low byte (it reschedules the compare match) */
    void *param;
    uint16_t buffered;
    int pending;
} compare_t;

typedef struct {
    avr_timer_t *timer;
    uint8_t temp; /* the high byte of a 16-bit write, until its low byte comes */
    compare_t compare[AVR_TIMER_COMP_COUNT];
} pwm_timer_t;

static pwm_timer_t timers[MAX_TIMERS];
static int n_timers;

static void load(avr_t *avr, compare_t *c, uint16_t value)
{
    avr->data[c->hi] = (uint8_t)(value >> 8);
    if (c->write)
        c->write(avr, c->lo, (uint8_t)value, c->param);
    else
        avr->data[c->lo] = (uint8_t)value;
}

static int double_buffered(const avr_timer_t *t)
{
    return t->tov_cycles > 0 && t->mode.kind == avr_timer_wgm_fast_pwm;
}

/* Just after BOTTOM: the buffers become the compare registers for the frame that has begun. */
static avr_cycle_count_t at_bottom(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)when;
    pwm_timer_t *t = param;
    for (int i = 0; i < AVR_TIMER_COMP_COUNT; i++) {
        compare_t *c = &t->compare[i];
        if (c->pending) {
            c->pending = 0;
            load(avr, c, c->buffered);
        }
    }
    return 0;
}

static void write_high(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)avr;
    (void)addr;
    ((pwm_timer_t *)param)->temp = v;
}

static void write_low(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    pwm_timer_t *t = param;
    compare_t *c = NULL;
    for (int i = 0; i < AVR_TIMER_COMP_COUNT && !c; i++)
        if (t->compare[i].lo == addr)
            c = &t->compare[i];
    if (!c)
        return;
    uint16_t value = (uint16_t)(t->temp << 8 | v);
    avr_timer_t *timer = t->timer;
    if (!double_buffered(timer)) {
        c->pending = 0;
        load(avr, c, value);
        return;
    }
    c->buffered = value;
    c->pending = 1;
    uint64_t into = (avr->cycle - timer->tov_base) % timer->tov_cycles;
    avr_cycle_timer_register(avr, timer->tov_cycles - into + 1, at_bottom, t);
}

void ocr_attach(harness_t *h)
{
    avr_t *avr = h->avr;
    n_timers = 0;
    for (avr_io_t *io = avr->io_port; io && n_timers < MAX_TIMERS; io = io->next) {
        if (!io->kind || strcmp(io->kind, "timer") != 0)
            continue;
        avr_timer_t *timer = (avr_timer_t *)io;
        pwm_timer_t *t = &timers[n_timers];
        memset(t, 0, sizeof *t);
        t->timer = timer;
        int any = 0;
        for (int i = 0; i < AVR_TIMER_COMP_COUNT; i++) {
            avr_timer_comp_t *comp = &timer->comp[i];
            if (!comp->r_ocr || !comp->r_ocrh) /* 8-bit timers and absent compare units */
                continue;
            compare_t *c = &t->compare[i];
            c->lo = comp->r_ocr;
            c->hi = comp->r_ocrh;
            c->write = avr->io[AVR_DATA_TO_IO(c->lo)].w.c;
            c->param = avr->io[AVR_DATA_TO_IO(c->lo)].w.param;
            avr->io[AVR_DATA_TO_IO(c->lo)].w.c = write_low;
            avr->io[AVR_DATA_TO_IO(c->lo)].w.param = t;
            avr->io[AVR_DATA_TO_IO(c->hi)].w.c = write_high;
            avr->io[AVR_DATA_TO_IO(c->hi)].w.param = t;
            any = 1;
        }
        if (any)
            n_timers++;
    }
}

void ocr_reset(harness_t *h)
{
    /* A reset clears the compare registers (simavr zeroes them) and with them what was buffered. */
    for (int k = 0; k < n_timers; k++) {
        pwm_timer_t *t = &timers[k];
        avr_cycle_timer_cancel(h->avr, at_bottom, t);
        t->temp = 0;
        for (int i = 0; i < AVR_TIMER_COMP_COUNT; i++)
            t->compare[i].pending = 0;
    }
}
