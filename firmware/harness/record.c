/*
 * record.c - what the harness saw, one event a line, times in cycles of harness time (--record FILE).
 *
 *   E <cycle> <pin> <level>   a pulse output pin changed (pin = channel 0..11 of board_pins.h)
 *   R <cycle> <cause>         the MCU left reset and starts running (cause: 0 power-on, 1 watchdog,
 *                             2 brown-out, 3 external); its uptime counts from here
 *   B <cycle> <1|0>           the brown-out detector began / stopped holding the MCU in reset
 *   H <cycle> <1|0>           the watchdog self-test pin was pulled low / released
 *   S <cycle> <1|0>           the ESC supply cut pin went high (supply cut) / low (supply on)
 *   M <cycle> <hex>           the watched RAM ("watch" command) as it is now, written when it changed
 *                             (checked at every rising pulse edge and after every slice)
 *   T <cycle>                 a time mark written on every flush (the file is complete up to here)
 * Pulses still high when a reset begins are cut short: a reader must drop them (see firmware_sim/avr).
 *
 * A pulse pin's edges are stamped on its timer's clock: simavr raises a compare or overflow output at the
 * end of the instruction it falls in, up to a few cycles late (an interrupt entry is 5), which would make
 * widths measured to the cycle jitter by more than half a 0.5 us timer tick (8 cycles). The true edge lies
 * on the timer's tick grid (its last overflow plus whole ticks), so an edge is stamped at the grid point at
 * or before the cycle it was seen in.
 */
#include <stdarg.h>

#include <string.h>

#include <avr_ioport.h>
#include <avr_timer.h>
#include <sim_io.h>
#include <sim_irq.h>

#include "../include/board_pins.h"
#include "harness.h"

static harness_t *recorder;
static avr_irq_t *pin_irq[PULSE_CHANNELS_HW];
static avr_timer_t *pin_timer[PULSE_CHANNELS_HW]; /* the 16-bit timer whose compare unit drives the pin */
static const char PIN_TIMERS[] = "111333444555";  /* board_pins.h: OC1A..OC5C */

/* Harness time of an edge seen now on `pin`: the timer tick at or before now (see the header). */
static uint64_t edge_time(const harness_t *h, unsigned pin)
{
    const avr_timer_t *t = pin_timer[pin];
    uint64_t cycle = h->avr->cycle;
    uint64_t tick = t ? t->cs_div_value : 0; /* cycles per timer tick (the prescaler) */
    if (tick && tick <= 1024 && t->tov_base && t->tov_base <= cycle)
        cycle -= (cycle - t->tov_base) % tick;
    return cycle + h->held_cycles;
}

static void on_supply_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    harness_t *h = recorder;
    int cut = value != 0;
    if (cut == h->esc_supply_cut)
        return;
    h->esc_supply_cut = cut;
    record_line(h, "S %llu %d\n", (unsigned long long)harness_now(h), cut);
}

void record_line(harness_t *h, const char *fmt, ...)
{
    if (!h->record)
        return;
    va_list ap;
    va_start(ap, fmt);
    vfprintf(h->record, fmt, ap);
    va_end(ap);
}

void record_flush(harness_t *h)
{
    record_line(h, "T %llu\n", (unsigned long long)harness_now(h));
    if (h->record)
        fflush(h->record);
    h->last_flush = harness_now(h);
}

void record_watch(harness_t *h)
{
    if (!h->watch_len)
        return;
    const uint8_t *now = h->avr->data + h->watch_addr;
    if (h->watch_valid && !memcmp(now, h->watched, h->watch_len))
        return;
    memcpy(h->watched, now, h->watch_len);
    h->watch_valid = 1;
    record_line(h, "M %llu ", (unsigned long long)harness_now(h));
    for (unsigned i = 0; i < h->watch_len; i++)
        record_line(h, "%02x", now[i]);
    record_line(h, "\n");
}

static void on_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = recorder;
    unsigned pin = (unsigned)(uintptr_t)param;
    uint64_t now = edge_time(h, pin);
    int level = value != 0;
    if (level == h->level[pin])
        return;
    h->level[pin] = level;
    if (level) {
        record_watch(h); /* the firmware's state as this pulse starts */
        h->rise[pin] = now;
    } else if (h->rise[pin]) {
        h->pulse_us[pin] = (uint16_t)((now - h->rise[pin]) * 1000000u / h->freq);
    }
    record_line(h, "E %llu %u %d\n", (unsigned long long)now, pin, level);
}

void record_attach(harness_t *h)
{
    static const char ports[] = PULSE_PIN_PORTS;
    static const int bits[] = PULSE_PIN_BITS;
    recorder = h;
    for (avr_io_t *io = h->avr->io_port; io; io = io->next) {
        if (!io->kind || strcmp(io->kind, "timer") != 0)
            continue;
        avr_timer_t *t = (avr_timer_t *)io;
        for (unsigned pin = 0; pin < PULSE_CHANNELS_HW; pin++)
            if (PIN_TIMERS[pin] == t->name)
                pin_timer[pin] = t;
    }
    /* Each pulse pin is watched at its timer's compare output, not at the port: on the chip a compare
     * output overrides PORTx, but simavr 1.6 re-raises every output pin of a port with its PORTx latch
     * bit on any write to PORTx/DDRx, so the SPI chip select on PB0 (the USB host, board_pins.h) would
     * "end" the OC1A..C pulses on PB5..PB7 at the first write after they rose. */
    for (unsigned pin = 0; pin < PULSE_CHANNELS_HW; pin++) {
        avr_timer_t *t = pin_timer[pin];
        pin_irq[pin] = t ? t->io.irq + TIMER_IRQ_OUT_COMP + pin % 3u
                         : avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(ports[pin]), bits[pin]);
        avr_irq_register_notify(pin_irq[pin], on_pin, (void *)(uintptr_t)pin);
    }
    avr_irq_t *supply = avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(ESC_SUPPLY_PIN_PORT), ESC_SUPPLY_PIN_BIT);
    avr_irq_register_notify(supply, on_supply_pin, NULL);
}

void record_reset(harness_t *h, int cause)
{
    /* A reset turns every output off: forget pulses in flight (the reader drops them as cut short). */
    for (unsigned pin = 0; pin < PULSE_CHANNELS_HW; pin++) {
        h->level[pin] = 0;
        h->pulse_us[pin] = 0;
        h->rise[pin] = 0;
        avr_raise_irq(pin_irq[pin], 0);
    }
    if (h->esc_supply_cut) { /* the pin is an input again: the pull-down switches the supply back on */
        h->esc_supply_cut = 0;
        record_line(h, "S %llu 0\n", (unsigned long long)harness_now(h));
    }
    if (cause >= 0)
        record_line(h, "R %llu %d\n", (unsigned long long)harness_now(h), cause);
}
