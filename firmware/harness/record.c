/*
 * record.c - what the harness saw, one event a line, times in cycles of harness time (--record FILE).
 *
 *   E <cycle> <pin> <level>   a pulse output pin changed (pin = channel 0..11 of board_pins.h)
 *   R <cycle> <cause>         the MCU left reset and starts running (cause: 0 power-on, 1 watchdog,
 *                             2 brown-out, 3 external); its uptime counts from here
 *   B <cycle> <1|0>           the brown-out detector began / stopped holding the MCU in reset
 *   H <cycle> <1|0>           the watchdog self-test pin was pulled low / released
 *   S <cycle> <1|0>           the ESC supply cut pin went high (supply cut) / low (supply on)
 *   T <cycle>                 a time mark written on every flush (the file is complete up to here)
 * Pulses still high when a reset begins are cut short: a reader must drop them (see firmware_sim/avr).
 */
#include <stdarg.h>

#include <avr_ioport.h>
#include <sim_io.h>
#include <sim_irq.h>

#include "../include/board_pins.h"
#include "harness.h"

static harness_t *recorder;
static avr_irq_t *pin_irq[PULSE_CHANNELS_HW];

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

static void on_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = recorder;
    unsigned pin = (unsigned)(uintptr_t)param;
    uint64_t now = harness_now(h);
    int level = value != 0;
    if (level == h->level[pin])
        return;
    h->level[pin] = level;
    if (level) {
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
    for (unsigned pin = 0; pin < PULSE_CHANNELS_HW; pin++) {
        pin_irq[pin] = avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(ports[pin]), bits[pin]);
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
