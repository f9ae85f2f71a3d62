/*
 * usb_check.c - the firmware's USB host stack (max3421e.c, usb_host.c, aoa.c) on the host, wired to the
 * MAX3421E + phone model (harness/max3421e.c) instead of the ATmega's SPI, for build/libusb-check.so.
 *
 * spi.h's functions call the model directly; time is simulated: every SPI byte takes 1 us (the ADK's
 * SPI runs at 8 MHz, a byte plus the AVR's loop overhead is ~1-2 us) and usbc_step() moves the clock by
 * the main-loop pass it stands for before the pass runs. The link layer's side (the board's transmit
 * queue, the event log) is a ring and an array here, so the tests see what the firmware's app would.
 * One stack per process (its state is static, as on the board): usbc_open() starts it afresh.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../harness/max3421e.h"
#include "aoa.h"
#include "spi.h"
#include "usb_host.h"

/* ------------------------------------------------------------------ the API the tests call */
int usbc_open(const char *serial);
void usbc_close(void);
uint64_t usbc_now(void);
int usbc_step(uint32_t pass_us);
void usbc_advance(uint32_t us);
long usbc_run_until(int aoa_state, uint32_t pass_us, uint32_t max_passes);
int usbc_host_state(void);
int usbc_version(void);
int usbc_fault(const char *name, double value);
size_t usbc_board_write(const uint8_t *buf, size_t len);
size_t usbc_board_read(uint8_t *buf, size_t cap);
size_t usbc_board_tx_pending(void);
size_t usbc_phone_write(const uint8_t *buf, size_t len);
size_t usbc_phone_read(uint8_t *buf, size_t cap);
int usbc_phone_mode(void);
const char *usbc_phone_string(int index);
const char *usbc_last_error(void);
int usbc_events(uint8_t *ev, uint16_t *arg, int cap);
void usbc_event_text(uint8_t ev, uint16_t arg, char *out, uint8_t n);
void usbc_stats(uint16_t *out);
void usbc_device(uint16_t *out);
uint32_t usbc_max_pass_us(void);
uint16_t usbc_refused(void);
int usbc_descriptor(int mode, int type, const uint8_t *bytes, size_t len);

static max3421e_t *chip;
static uint64_t now_us;
static char serial_copy[32];
static uint32_t pass_start, max_pass; /* the longest poll, in simulated us */

#define TX_SIZE 8192u
static uint8_t tx[TX_SIZE];
static size_t tx_head, tx_len;

#define MAX_EVENTS 64
static uint8_t ev_code[MAX_EVENTS];
static uint16_t ev_arg[MAX_EVENTS];
static int n_events;

/* ------------------------------------------------------------------ spi.h on the model */
void spi_init(void) {}

void spi_select(uint8_t on) { max3421e_select(chip, on); }

uint8_t spi_byte(uint8_t out)
{
    now_us += 1;
    max3421e_advance(chip, now_us);
    return max3421e_spi(chip, out);
}

uint8_t usb_int_asserted(void) { return (uint8_t)max3421e_int_asserted(chip); }

void usb_reset_pin(uint8_t low) { max3421e_reset_pin(chip, low); }

uint32_t usb_now_us(void)
{
    now_us += 1; /* reading the clock takes time too: a polling loop always advances */
    max3421e_advance(chip, now_us);
    return (uint32_t)now_us;
}

/* ------------------------------------------------------------------ the link layer's side */
uint16_t usb_tx_pending(void) { return (uint16_t)(tx_len > 0xFFFF ? 0xFFFF : tx_len); }

uint8_t usb_tx_peek(uint8_t *dst, uint8_t max)
{
    uint8_t n = tx_len < max ? (uint8_t)tx_len : max;
    for (uint8_t i = 0; i < n; i++)
        dst[i] = tx[(tx_head + i) % TX_SIZE];
    return n;
}

void usb_tx_consume(uint8_t n)
{
    if (n > tx_len)
        n = (uint8_t)tx_len;
    tx_head = (tx_head + n) % TX_SIZE;
    tx_len -= n;
}

void usb_link_event(uint8_t ev, uint16_t arg)
{
    if (n_events < MAX_EVENTS) {
        ev_code[n_events] = ev;
        ev_arg[n_events] = arg;
        n_events++;
    }
}

/* ------------------------------------------------------------------ API */
int usbc_open(const char *serial)
{
    usbc_close();
    chip = max3421e_new();
    if (!chip)
        return -1;
    now_us = 0;
    max3421e_advance(chip, now_us);
    tx_head = tx_len = 0;
    n_events = 0;
    max_pass = 0;
    snprintf(serial_copy, sizeof serial_copy, "%s", serial ? serial : "");
    usb_stats = (usb_stats_t){0};
    aoa_init(serial_copy);
    return 0;
}

void usbc_close(void)
{
    if (chip)
        max3421e_free(chip);
    chip = NULL;
}

uint64_t usbc_now(void) { return now_us; }

/* One main-loop pass `pass_us` after the last: the stack's state after it. */
int usbc_step(uint32_t pass_us)
{
    now_us += pass_us;
    max3421e_advance(chip, now_us);
    pass_start = (uint32_t)now_us;
    aoa_poll((uint32_t)now_us);
    uint32_t took = (uint32_t)now_us - pass_start;
    if (took > max_pass)
        max_pass = took;
    return aoa_state();
}

/* Simulated time moves `us` with no pass of the stack: the chip and the phone go on (a reset ends, a
 * transfer completes) while the board is busy elsewhere, between two looks at the chip. */
void usbc_advance(uint32_t us)
{
    now_us += us;
    max3421e_advance(chip, now_us);
}

/* Passes until the accessory layer is in `aoa_state` (the count), or -1 after max_passes. */
long usbc_run_until(int state, uint32_t pass_us, uint32_t max_passes)
{
    for (uint32_t i = 0; i < max_passes; i++)
        if (usbc_step(pass_us) == state)
            return (long)i + 1;
    return -1;
}

int usbc_host_state(void) { return usb_host_state(); }

int usbc_version(void) { return aoa_protocol_version(); }

int usbc_fault(const char *name, double value) { return max3421e_fault(chip, name, value); }

size_t usbc_board_write(const uint8_t *buf, size_t len)
{
    size_t n = 0;
    for (; n < len && tx_len < TX_SIZE; n++, tx_len++)
        tx[(tx_head + tx_len) % TX_SIZE] = buf[n];
    return n;
}

size_t usbc_board_tx_pending(void) { return tx_len; }

size_t usbc_board_read(uint8_t *buf, size_t cap)
{
    size_t n = 0;
    while (n < cap && aoa_read(&buf[n]))
        n++;
    return n;
}

size_t usbc_phone_write(const uint8_t *buf, size_t len) { return max3421e_phone_write(chip, buf, len); }

size_t usbc_phone_read(uint8_t *buf, size_t cap) { return max3421e_phone_read(chip, buf, cap); }

int usbc_phone_mode(void) { return max3421e_phone_mode(chip); }

const char *usbc_phone_string(int index) { return max3421e_phone_string(chip, index); }

const char *usbc_last_error(void) { return max3421e_last_error(chip); }

int usbc_events(uint8_t *ev, uint16_t *arg, int cap)
{
    int n = n_events < cap ? n_events : cap;
    memcpy(ev, ev_code, (size_t)n);
    memcpy(arg, ev_arg, (size_t)n * sizeof *arg);
    return n_events;
}

void usbc_event_text(uint8_t ev, uint16_t arg, char *out, uint8_t n) { aoa_event_text(ev, arg, out, n); }

/* attaches, detaches, enum_failures, stalls, naks_ridden, xfer_errors, last_hr */
void usbc_stats(uint16_t *out)
{
    out[0] = usb_stats.attaches;
    out[1] = usb_stats.detaches;
    out[2] = usb_stats.enum_failures;
    out[3] = usb_stats.stalls;
    out[4] = usb_stats.naks_ridden;
    out[5] = usb_stats.xfer_errors;
    out[6] = usb_stats.last_hr;
}

/* vid, pid, max_packet0, bulk_in, bulk_out, in_packet, out_packet */
void usbc_device(uint16_t *out)
{
    out[0] = usb_dev.vid;
    out[1] = usb_dev.pid;
    out[2] = usb_dev.max_packet0;
    out[3] = usb_dev.bulk_in;
    out[4] = usb_dev.bulk_out;
    out[5] = usb_dev.in_packet;
    out[6] = usb_dev.out_packet;
}

uint32_t usbc_max_pass_us(void) { return max_pass; }

/* usb_stats.refused: kept out of usbc_stats, whose seven values the tests' buffers are sized for */
uint16_t usbc_refused(void) { return usb_stats.refused; }

/* The phone's descriptor of `type` (1 device, 2 configuration) in `mode` (1 normal, 2 accessory) replaced
 * by `len` bytes, malformed ones included (max3421e_descriptor): 0, or -1 if the model refuses it. */
int usbc_descriptor(int mode, int type, const uint8_t *bytes, size_t len)
{
    return max3421e_descriptor(chip, mode, type, bytes, len);
}
