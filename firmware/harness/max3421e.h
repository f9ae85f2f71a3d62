/*
 * max3421e.h - a register-level model of the MAX3421E USB host controller in host mode, with a full-speed
 * Android phone plugged into its port (normal mode first, Android Open Accessory after START).
 *
 * Pure C, no simavr types: the simavr harness (usb.c) wires it to the MCU's SPI and GPIO pins, and the
 * host test build (libmax3421e-model.so, libusb-check.so) calls it directly, so the very same model is
 * exercised from Python through ctypes and by the real firmware under simavr.
 *
 * Time is simulated: the caller moves it with max3421e_advance() (microseconds since an arbitrary epoch,
 * never decreasing). A transaction launched by writing HXFR completes only after a realistic delay, so a
 * driver must wait for HXFRDNIRQ as on the real chip.
 */
#ifndef MAX3421E_MODEL_H
#define MAX3421E_MODEL_H

#include <stddef.h>
#include <stdint.h>

typedef struct max3421e max3421e_t; /* opaque */

max3421e_t *max3421e_new(void);                    /* a chip with a phone attached (normal mode, AOA v2) */
void max3421e_free(max3421e_t *m);
void max3421e_select(max3421e_t *m, int selected); /* SS: 1 = driven low (a command starts), 0 = released (it ends) */
uint8_t max3421e_spi(max3421e_t *m, uint8_t mosi); /* one full-duplex SPI byte while selected; returns MISO */
int max3421e_int_asserted(const max3421e_t *m);    /* the INT pin is asserted (IE & IRQ bits, per IENB/CPUCTL.IE, level mode) */
void max3421e_reset_pin(max3421e_t *m, int low);   /* the chip's RES pin (held low = chip reset) */
void max3421e_advance(max3421e_t *m, uint64_t now_us); /* simulated time: 1 ms frames (FRAMEIRQ/SOF), device latencies, bus events */

/* The phone's app side of the accessory bulk pipes (bytes, not packets). */
size_t max3421e_phone_read(max3421e_t *m, uint8_t *buf, size_t cap);         /* bytes the board sent on bulk OUT */
size_t max3421e_phone_write(max3421e_t *m, const uint8_t *buf, size_t len);  /* queue bytes for bulk IN; returns accepted */

/* State and faults. */
int max3421e_phone_mode(const max3421e_t *m);                      /* 0 detached, 1 normal (not accessory), 2 accessory */
const char *max3421e_phone_string(const max3421e_t *m, int index); /* identity string recorded by SEND_STRING (0..5), "" if none */
/* 0 ok, -1 unknown name/value. Names:
 *   "nak"    value = number of NAKs to answer on every following bulk/control data transaction (0 = off)
 *   "stall"  value = endpoint number whose next transaction is STALLed once
 *   "detach", "attach" (value ignored)
 *   "aoa"    value = AOA protocol version the phone reports: 0, 1, 2
 *   "packet" value = max bytes per bulk IN packet, 1..64 (a frame then straddles packet boundaries)
 *   "zlp"    value 1: end each bulk IN transfer that is a multiple of 64 bytes with a zero-length packet
 *   "never_switch" value 1: AOA START is acknowledged but the phone never re-enumerates as an accessory
 *            (no accessory app, or AOA barred by policy); 2: it drops off the bus as for a switch but comes
 *            back in its normal mode (a new device to the host, every time); 0 (the default): it switches
 *   "osc"    value 0: the chip's crystal does not start (OSCOKIRQ never rises, whatever resets it); 1 (the
 *            default): it starts OSC_START_US after each reset
 *   "lost_ack" value N: the next N bulk OUT packets the accessory takes lose their ACK on the way back: the
 *            phone has the bytes (its toggle moved on), the chip reports hrTIMEOUT. A host must send that
 *            very packet again (the phone discards it as a repeat); a different one is bytes lost, reported
 *            in last_error
 *   "config_value" value 0..255: the bConfigurationValue of the phone's configuration (both modes; 1 by
 *            default); SET_CONFIGURATION takes that value or 0 (0: back to the address state, endpoints
 *            other than 0 unanswered). A value of 0 is absurd: a configuration no host can select
 *   "ep0_packet" value 0..255: the bMaxPacketSize0 of the phone's device descriptor (both modes; 64 by
 *            default), also the size of its endpoint-0 data packets (clamped to 1..64). Full speed allows
 *            only 8, 16, 32 and 64: any other value is a descriptor a host must refuse
 *   "condet_after_reset" value N (us, 0..100000; 0 = off, the default): the chip raises CONDETIRQ N us after
 *            each bus reset ends, the phone still there (a chip whose reset's own end is seen late as a
 *            connect event): a driver must not take it for a replug at every reset (a reset loop)
 *   "clear_halt_nak" value 1: the phone NAKs the status stage of every CLEAR_FEATURE(ENDPOINT_HALT) for ever
 *            (0, the default: it takes them); with "stall" re-armed, an endpoint no clear ever mends */
int max3421e_fault(max3421e_t *m, const char *name, double value);
/* Replace the phone's descriptor of `type` (1 device, 2 configuration) in `mode` (1 normal, 2 accessory, as
 * max3421e_phone_mode says) with `len` bytes, served as they are - a malformed one too - to GET_DESCRIPTOR
 * (at most the wLength asked): a device descriptor up to 64 bytes, a configuration up to 1024. The phone's
 * endpoints are those the accessory configuration's descriptors say, as far as they parse. 0 ok, -1 an
 * unknown mode/type or too long. */
int max3421e_descriptor(max3421e_t *m, int mode, int type, const uint8_t *bytes, size_t len);
const char *max3421e_last_error(const max3421e_t *m); /* the last protocol violation the board made ("" if none) */

#endif /* MAX3421E_MODEL_H */
