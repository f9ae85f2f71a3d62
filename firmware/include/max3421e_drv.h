/*
 * max3421e_drv.h - the MAX3421E USB host controller, register level: SPI register access, chip reset,
 * host mode, bus sampling (speed detection), bus reset, and one host transaction (HXFR) with a bounded
 * wait. Register numbers and bits as the Maxim MAX3421E datasheet and its programming guide (AN3785)
 * name them. Portable: hardware only through spi.h. Callers (usb_host.c) keep the state machines.
 */
#ifndef MAX3421E_DRV_H
#define MAX3421E_DRV_H

#include <stdint.h>

/* Registers (the number; the SPI command byte is reg << 3 | write << 1). */
enum {
    MAX_RCVFIFO = 1, MAX_SNDFIFO = 2, MAX_SUDFIFO = 4, MAX_RCVBC = 6, MAX_SNDBC = 7,
    MAX_USBIRQ = 13, MAX_USBIEN = 14, MAX_USBCTL = 15, MAX_CPUCTL = 16, MAX_PINCTL = 17,
    MAX_REVISION = 18, MAX_HIRQ = 25, MAX_HIEN = 26, MAX_MODE = 27, MAX_PERADDR = 28, MAX_HCTL = 29,
    MAX_HXFR = 30, MAX_HRSL = 31,
};

/* USBIRQ */
#define MAX_OSCOKIRQ 0x01u
/* USBCTL */
#define MAX_CHIPRES 0x20u
/* CPUCTL */
#define MAX_IE 0x01u
/* PINCTL */
#define MAX_FDUPSPI 0x10u
#define MAX_INTLEVEL 0x08u
/* HIRQ / HIEN */
#define MAX_BUSEVENTIRQ 0x01u
#define MAX_RCVDAVIRQ 0x04u
#define MAX_SNDBAVIRQ 0x08u
#define MAX_CONDETIRQ 0x20u
#define MAX_FRAMEIRQ 0x40u
#define MAX_HXFRDNIRQ 0x80u
/* MODE */
#define MAX_HOST 0x01u
#define MAX_LOWSPEED 0x02u
#define MAX_SOFKAENAB 0x08u
#define MAX_DMPULLDN 0x40u
#define MAX_DPPULLDN 0x80u
/* HCTL */
#define MAX_BUSRST 0x01u
#define MAX_SAMPLEBUS 0x04u
#define MAX_RCVTOG0 0x10u
#define MAX_RCVTOG1 0x20u
#define MAX_SNDTOG0 0x40u
#define MAX_SNDTOG1 0x80u
/* HXFR tokens (| endpoint number) */
#define MAX_TOK_SETUP 0x10u
#define MAX_TOK_IN 0x00u
#define MAX_TOK_OUT 0x20u
#define MAX_TOK_IN_HS 0x80u
#define MAX_TOK_OUT_HS 0xA0u
/* HRSL */
#define MAX_RCVTOGRD 0x10u
#define MAX_SNDTOGRD 0x20u
#define MAX_KSTATUS 0x40u
#define MAX_JSTATUS 0x80u
/* HRSL result codes (low nibble) */
enum {
    MAX_HR_SUCCESS = 0x0, MAX_HR_BUSY = 0x1, MAX_HR_NAK = 0x4, MAX_HR_STALL = 0x5, MAX_HR_TOGERR = 0x6,
    MAX_HR_TIMEOUT = 0xE,
    MAX_HR_NO_ANSWER = 0x10, /* not the chip's: HXFRDNIRQ did not come within MAX_XFER_WAIT_US */
};

/* How long one transaction may keep the caller waiting for HXFRDNIRQ (us). A full-speed 64-byte packet
 * takes ~50 us on the bus; the chip holds a transaction back for the next frame when it would collide
 * with a SOF, so a little over one 1 ms frame covers every legal case. */
#define MAX_XFER_WAIT_US 1200u

/* Bus state from HRSL's J/K bits after a sample (with MODE.LOWSPEED = 0: J = full speed, K = low speed). */
typedef enum { MAX_BUS_SE0 = 0, MAX_BUS_FULL, MAX_BUS_LOW, MAX_BUS_SE1 } max_bus_t;

uint8_t max_read(uint8_t reg);
void max_write(uint8_t reg, uint8_t value);
void max_read_fifo(uint8_t reg, uint8_t *dst, uint8_t n);
void max_write_fifo(uint8_t reg, const uint8_t *src, uint8_t n);

/* Full-duplex SPI, level INT; USBCTL.CHIPRES pulsed. The oscillator is then starting: poll
 * max_osc_ok() (the datasheet allows a few ms). */
void max_chip_reset(void);
uint8_t max_osc_ok(void);
/* Host mode with the D+/D- pull-downs, INT on CONDETIRQ (so an idle bus costs no SPI traffic). */
void max_host_mode(void);
/* Sample the bus (HCTL.SAMPLEBUS, bounded) and read J/K. */
max_bus_t max_sample_bus(void);
/* Speed for the attached device (LOWSPEED bit) with SOF/keep-alive generation on. */
void max_set_speed(max_bus_t bus);
/* Start a bus reset (HCTL.BUSRST); max_bus_reset_done() once the chip has ended it (~50 ms). */
void max_bus_reset(void);
uint8_t max_bus_reset_done(void);
/* Launch one transaction (token | endpoint) at the address in PERADDR and wait, bounded, for it:
 * the HRSL result code (MAX_HR_*), MAX_HR_NO_ANSWER if HXFRDNIRQ never came. */
uint8_t max_xfer(uint8_t token_ep);

#endif /* MAX3421E_DRV_H */
