/*
 * usb.c - the Mega ADK's USB host port under simavr (--usb): the MAX3421E model (max3421e.c) on the
 * ATmega2560's SPI and pins, with an Android phone plugged in whose accessory app is the pty.
 *
 * Wiring (board_pins.h, as the Mega ADK wires it):
 *   SPI  the MCU writing SPDR (SPE, MSTR) clocks one byte: the chip sees MOSI at once, and its MISO byte
 *        arrives through SPI_IRQ_INPUT (which sets SPIF and SPDR) 8 SCK periods later, as on the real
 *        part: 16 CPU cycles at fosc/2. simavr 1.6's own SPI master takes a fixed 100 us a byte whatever the
 *        clock (measured: 1616 cycles at 16 MHz), 100 times the real 1 us at 8 MHz, which would make every
 *        USB transfer a hundred times slower than on the bench; so the harness takes over the SPDR write
 *        (as ocr.c does for OCRn) and times the byte itself.
 *   SS   PB0, MCU output: low selects the chip (a command starts), high ends the command.
 *   INT  PE6, MCU input: driven low while the chip asserts INT (level mode, active low, open drain: the
 *        firmware's pull-up makes it high otherwise), high otherwise.
 *   RES  PJ2, MCU output: low holds the chip in reset. After an MCU reset the pin is an input and the
 *        board's pull-up keeps the chip running (assumed: the ADK schematic pulls MAX_RESET up), so a
 *        board reset does not reset the chip; the firmware resets it over SPI (CHIPRES) or with RES.
 * Time: the model follows the MCU's simulated time (harness_now, cycles at --freq) in microseconds,
 * advanced on every SPI byte and by a cycle timer every TICK_US, so INT and HXFRDNIRQ come when the chip
 * would raise them, whether the firmware polls HIRQ over SPI or watches the INT pin.
 *
 * The phone's app: bytes the host program writes on the pty are the app's writes (max3421e_phone_write;
 * while no accessory is open they are dropped and counted, as the app's write would fail; while the
 * phone's buffer is full they wait, as the app's write would block); what the board sends on bulk OUT is
 * read by the app and written to the pty. UART0 is not connected to the pty in this mode.
 */
#include <stdlib.h>
#include <string.h>

#include <avr_ioport.h>
#include <avr_spi.h>
#include <sim_cycle_timers.h>
#include <sim_io.h>
#include <sim_irq.h>

#include "../include/board_pins.h"
#include "harness.h"
#include "max3421e.h"

#define TICK_US 4u /* the model's clock steps at least this often: below its shortest transaction (8 us) */

static avr_irq_t *spi_input, *int_pin;
static uint8_t miso;

/* ATmega2560 SPI registers (data-space addresses) and bits. */
#define SPCR_ADDR 0x4C
#define SPSR_ADDR 0x4D
#define SPDR_ADDR 0x4E
#define SPCR_SPE 0x40
#define SPCR_MSTR 0x10
#define SPSR_SPIF 0x80
#define SPSR_SPI2X 0x01

static uint64_t now_us(const harness_t *h) { return harness_now(h) * 1000000u / h->freq; }

/* The INT line as the MCU reads it on PE6. Compared with the irq's own value (not a copy): the MCU's
 * writes to PORTE touch the same irq. */
static void drive_int(harness_t *h, int force)
{
    uint32_t level = max3421e_int_asserted(h->max) ? 0 : 1;
    if (force) { /* an MCU reset cleared PINE but not the irq's value: write it whatever it was */
        avr_raise_irq(int_pin, !level);
        avr_raise_irq(int_pin, level);
    } else if (int_pin->value != level) {
        avr_raise_irq(int_pin, level);
    }
}

static void catch_up(harness_t *h)
{
    max3421e_advance(h->max, now_us(h));
    drive_int(h, 0);
}

/* The byte's last SCK edge: MISO lands in SPDR and SPIF rises. */
static avr_cycle_count_t spi_done(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr;
    (void)when;
    avr_raise_irq(spi_input, miso);
    drive_int(param, 0);
    return 0;
}

static void on_spdr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    harness_t *h = param;
    avr->data[addr] = v;
    uint8_t spcr = avr->data[SPCR_ADDR];
    if (!(spcr & SPCR_SPE) || !(spcr & SPCR_MSTR))
        return; /* no master, no clock: nothing moves */
    avr->data[SPSR_ADDR] &= (uint8_t)~SPSR_SPIF; /* as writing SPDR after reading SPSR clears it */
    catch_up(h);
    miso = max3421e_spi(h->max, v);
    h->usb_spi_bytes++;
    static const uint8_t divider[4] = {4, 16, 64, 128};
    uint32_t sck = divider[spcr & 3] >> (avr->data[SPSR_ADDR] & SPSR_SPI2X ? 1 : 0);
    avr_cycle_timer_register(avr, 8u * sck, spi_done, h);
}

static void on_ss(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = param;
    catch_up(h);
    max3421e_select(h->max, value == 0);
}

static void on_res(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = param;
    catch_up(h);
    max3421e_reset_pin(h->max, value == 0);
    drive_int(h, 0);
}

static avr_cycle_count_t on_tick(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr;
    harness_t *h = param;
    catch_up(h);
    return when + (avr_cycle_count_t)h->freq * TICK_US / 1000000u;
}

int usb_attach(harness_t *h)
{
    h->max = max3421e_new();
    if (!h->max)
        return -1;
    spi_input = avr_io_getirq(h->avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_INPUT);
    int_pin = avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(USB_INT_PIN_PORT), USB_INT_PIN_BIT);
    avr_irq_t *ss = avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(USB_SS_PIN_PORT), USB_SS_PIN_BIT);
    avr_irq_t *res = avr_io_getirq(h->avr, AVR_IOCTL_IOPORT_GETIRQ(USB_RES_PIN_PORT), USB_RES_PIN_BIT);
    if (!spi_input || !int_pin || !ss || !res)
        return -1;
    spi_input->flags &= (uint8_t)~IRQ_FLAG_FILTERED; /* the same MISO byte twice is two bytes */
    h->avr->io[AVR_DATA_TO_IO(SPDR_ADDR)].w.c = on_spdr_write; /* simavr's SPI module keeps its read */
    h->avr->io[AVR_DATA_TO_IO(SPDR_ADDR)].w.param = h;
    avr_irq_register_notify(ss, on_ss, h);
    avr_irq_register_notify(res, on_res, h);
    usb_reset(h);
    return 0;
}

void usb_reset(harness_t *h)
{
    if (!h->max)
        return;
    /* The MCU's pins are inputs again: SS floats high (deselected), RES is pulled up. */
    max3421e_select(h->max, 0);
    max3421e_reset_pin(h->max, 0);
    drive_int(h, 1);
    avr_cycle_timer_cancel(h->avr, on_tick, h);
    avr_cycle_timer_register_usec(h->avr, TICK_US, on_tick, h);
}

/* The phone app's side of the accessory, between the pty queues and the model (bridge_service). */
void usb_service(harness_t *h)
{
    catch_up(h);
    while (h->rxq_head != h->rxq_tail) {
        uint32_t n = h->rxq_tail - h->rxq_head, at = h->rxq_head % (uint32_t)sizeof h->rxq;
        if (n > (uint32_t)sizeof h->rxq - at)
            n = (uint32_t)sizeof h->rxq - at; /* up to the ring's end: one write at a time */
        size_t took = max3421e_phone_write(h->max, h->rxq + at, n);
        if (took == 0) {
            if (max3421e_phone_mode(h->max) != 2) { /* no accessory open: the app's write fails */
                h->usb_dropped += h->rxq_tail - h->rxq_head;
                h->rxq_head = h->rxq_tail;
            }
            break; /* else the phone's buffer is full: the app's write blocks, the bytes wait */
        }
        h->usb_to_board += took;
        h->rxq_head += (uint32_t)took;
    }
    uint8_t buf[512];
    for (size_t n; (n = max3421e_phone_read(h->max, buf, sizeof buf)) > 0;) {
        h->usb_from_board += n;
        for (size_t i = 0; i < n; i++)
            bridge_transmit(h, buf[i]);
    }
    drive_int(h, 0);
}

/* "usb detach", "usb attach", "usb <fault> <value>" and "usbstate" (control.c). */
static void put_hex(FILE *out, const char *s)
{
    if (!*s) {
        fputs(" -", out);
        return;
    }
    fputc(' ', out);
    for (; *s; s++)
        fprintf(out, "%02x", (unsigned char)*s);
}

void usb_command(harness_t *h, int argc, char **argv, FILE *out)
{
    if (!h->max) {
        fprintf(out, "error %s: only with --usb\n", argv[0]);
    } else if (!strcmp(argv[0], "usbstate") && argc == 1) {
        catch_up(h);
        fprintf(out, "ok %d", max3421e_phone_mode(h->max));
        for (int i = 0; i < 6; i++)
            put_hex(out, max3421e_phone_string(h->max, i));
        put_hex(out, max3421e_last_error(h->max));
        fprintf(out, " %llu %llu %llu %llu\n", (unsigned long long)h->usb_to_board,
                (unsigned long long)h->usb_from_board, (unsigned long long)h->usb_dropped,
                (unsigned long long)h->usb_spi_bytes);
    } else if (!strcmp(argv[0], "usb") && (argc == 3 || (argc == 2 && (!strcmp(argv[1], "detach") ||
                                                                       !strcmp(argv[1], "attach"))))) {
        char *end = NULL;
        double value = argc == 3 ? strtod(argv[2], &end) : 0;
        catch_up(h);
        if ((argc == 3 && *end) || max3421e_fault(h->max, argv[1], value) < 0) {
            fprintf(out, "error usb: unknown fault or value: %s %s (nak N, stall EP, detach, attach, aoa 0|1|2, "
                         "packet 1..64, zlp 0|1, never_switch 0|1|2, osc 0|1, config_value 0..255, lost_ack N, "
                         "ep0_packet 0..255, condet_after_reset US, clear_halt_nak 0|1)\n",
                    argv[1], argc == 3 ? argv[2] : "");
        } else {
            drive_int(h, 0);
            fprintf(out, "ok %llu\n", (unsigned long long)harness_now(h));
        }
    } else {
        fprintf(out, "error usb: usage: usb detach | usb attach | usb <fault> <value> | usbstate\n");
    }
}

void usb_close(harness_t *h)
{
    max3421e_free(h->max);
    h->max = NULL;
}
