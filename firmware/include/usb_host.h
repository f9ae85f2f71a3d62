/*
 * usb_host.h - a one-device USB host on the MAX3421E: attach detection, debounce, bus reset and speed,
 * enumeration (device descriptor 8 then 18 bytes, SET_ADDRESS, configuration descriptor, SET_CONFIGURATION;
 * a configuration descriptor shorter than 9 bytes, of bConfigurationValue 0, holding a descriptor shorter
 * than its type's standard size (configuration/interface 9, endpoint 7, any other 2) or cut by its
 * wTotalLength fails it; a device descriptor that comes back short, is not one (bLength other than 18,
 * bDescriptorType other than 1) or says a bMaxPacketSize0 other than 8/16/32/64 is refused: USB_REFUSED),
 * detach; plus the non-blocking control-transfer engine and single bulk transactions the accessory layer
 * (aoa.c) uses.
 *
 * Everything is a state machine advanced by usb_host_poll() from the main loop: one call does a bounded
 * amount of work (a few transactions, each waiting at most MAX_XFER_WAIT_US for the chip), so the link
 * watchdog, the pulses and the MCU watchdog are never held up by the bus. Times in microseconds from
 * usb_now_us() (spi.h). RAM: one device, one control transfer at a time (see the size report).
 */
#ifndef USB_HOST_H
#define USB_HOST_H

#include <stdint.h>

typedef enum {
    USB_OFF = 0,      /* before usb_host_init */
    USB_OSC_WAIT,     /* chip reset, waiting for its oscillator (OSCOKIRQ) */
    USB_CHIP_DEAD,    /* the oscillator never came: the chip is tried again after USB_RETRY_US */
    USB_DETACHED,     /* host mode, nothing on the port */
    USB_SETTLE,       /* something attached: debounce */
    USB_RESETTING,    /* bus reset in progress */
    USB_RESET_RECOVERY, /* SOFs running, the device's reset recovery time */
    USB_ENUMERATING,  /* control transfers of the enumeration (usb_host.c's steps) */
    USB_CONFIGURED,   /* configured: the accessory layer owns it */
    USB_ERROR,        /* enumeration failed USB_ENUM_TRIES times: waits for a detach or USB_RETRY_US */
    USB_REFUSED,      /* a device descriptor no host may take (short, not a device descriptor, or a
                         bMaxPacketSize0 full speed does not allow): left unconfigured, no retry, until it is
                         unplugged */
} usb_state_t;

#define USB_DEBOUNCE_US 200000UL     /* attach debounce (USB 2.0 9.1.2 asks for >= 100 ms) */
#define USB_RECOVERY_US 20000UL      /* after the bus reset, SOFs before the first request (>= 10 ms) */
#define USB_RESET_MAX_US 100000UL    /* the chip ends a bus reset in ~50 ms: later than this is a fault */
#define USB_OSC_MAX_US 20000UL       /* the chip's oscillator settles in a few ms */
#define USB_CTL_TIMEOUT_US 500000UL  /* one control transfer, NAKs included (USB allows 5 s: we retry sooner) */
#define USB_SET_ADDRESS_US 2000UL    /* SET_ADDRESS recovery interval (USB 2.0 9.2.6.3) */
#define USB_RETRY_US 1000000UL       /* a dead chip or a failed enumeration is tried again after this */
#define USB_ENUM_TRIES 3u            /* bus reset + enumeration attempts before USB_ERROR */
#define USB_XFERS_PER_POLL 4u        /* transactions one poll may run (each <= MAX_XFER_WAIT_US) */
#define USB_DEVICE_ADDRESS 1u

typedef struct {
    uint8_t bmRequestType, bRequest;
    uint16_t wValue, wIndex, wLength;
} usb_setup_t;

/* IN data of a control transfer, packet by packet (at most max_packet0 bytes each). */
typedef void (*usb_in_sink_t)(const uint8_t *data, uint8_t n);

typedef enum { USB_CTL_BUSY = 0, USB_CTL_DONE, USB_CTL_FAILED } usb_ctl_result_t;

typedef struct {
    uint16_t vid, pid;
    uint8_t max_packet0; /* bMaxPacketSize0 as the device said it (8 until it has; checked after the read;
                            USB_REFUSED: 0 if the descriptor ended before it or was no device descriptor) */
    uint8_t config_value;
    uint8_t bulk_in, bulk_out;   /* endpoint numbers of interface 0's bulk pair in its default (alternate 0)
                                    setting, the one configured (0: none found) */
    uint8_t in_packet, out_packet; /* their wMaxPacketSize (<= 64 at full speed) */
    uint8_t low_speed;
} usb_device_t;

typedef struct {
    uint16_t attaches, detaches, enum_failures, stalls, naks_ridden, xfer_errors;
    uint8_t last_hr; /* the last failed transaction's HRSL code (MAX_HR_*) */
    uint8_t refused; /* devices left unconfigured for their device descriptor (USB_REFUSED; held at 255) */
} usb_stats_t;

extern usb_device_t usb_dev;
extern usb_stats_t usb_stats;

void usb_host_init(void);
/* Advance the host state machine (attach, detach, enumeration) at `now_us`. */
void usb_host_poll(uint32_t now_us);
usb_state_t usb_host_state(void);
/* Counts every bus attach/detach the host saw (the accessory layer compares it to notice either). */
uint8_t usb_host_generation(void);
/* Drop the device: bus reset and enumerate again (after an unrecoverable pipe error). */
void usb_host_reenumerate(void);

/* Control transfers on endpoint 0 of the configured device: start one (OUT data from `out`, in flash
 * if out_flash, wLength bytes; IN data to `sink`), then poll it until it is not busy. */
void usb_ctl_start(const usb_setup_t *s, const uint8_t *out, uint8_t out_flash, usb_in_sink_t sink);
usb_ctl_result_t usb_ctl_poll(uint32_t now_us);
uint8_t usb_ctl_result_hr(void);

/* One bulk IN transaction on endpoint `ep` with its data toggle in *toggle (updated): the HRSL code.
 * On MAX_HR_SUCCESS the packet's *n bytes (<= 64) are left in the chip's RCVFIFO for the caller to read
 * (max_read(MAX_RCVFIFO)) and free (HIRQ.RCVDAVIRQ) - a zero-length packet is freed here. */
uint8_t usb_bulk_in(uint8_t ep, uint8_t *toggle, uint8_t *n);
/* One bulk OUT transaction of n bytes (0: a zero-length packet): the HRSL code. */
uint8_t usb_bulk_out(uint8_t ep, uint8_t *toggle, const uint8_t *src, uint8_t n);

#endif /* USB_HOST_H */
