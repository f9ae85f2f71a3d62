/*
 * aoa.h - the board as an Android Open Accessory host: on a configured device (usb_host.h) either open
 * the accessory's bulk pair (vendor 0x18D1, product 0x2D00..0x2D05) or switch the phone into accessory
 * mode (GET_PROTOCOL 51, SEND_STRING 52 x6 with the board's identity strings, START 53) and wait for it to
 * come back as an accessory; then move the protocol's bytes over the bulk pipes (docs/protocol.md, AOA).
 *
 * Bytes: bulk IN is polled only when the previous packet has been read out (aoa_read), so the phone
 * holds what the board has not taken yet (USB's own flow control, no ring here). Bulk OUT drains the
 * link's transmit queue (usb_tx_* below, provided by the link layer) in packets of the endpoint's size;
 * the board's writes are a byte stream, not transfers: when a packet is full and the queue is then
 * empty, a zero-length packet ends the transfer so the phone's read() returns (Android's accessory
 * driver completes a read on a short packet or a full buffer). A packet that got no handshake (a bus
 * error: the phone may hold it, its ACK lost) goes again exactly as it was, never grown by bytes queued
 * since: the phone discards a repeat whole, and what was added to it would be lost.
 */
#ifndef AOA_H
#define AOA_H

#include <stdint.h>

#define AOA_GOOGLE_VID 0x18D1u
#define AOA_PID_FIRST 0x2D00u /* accessory */
#define AOA_PID_LAST 0x2D05u  /* accessory + audio + adb */
#define AOA_REQ_GET_PROTOCOL 51u
#define AOA_REQ_SEND_STRING 52u
#define AOA_REQ_START 53u
#define AOA_STRINGS 6u
#define AOA_REENUM_US 3000000UL /* after START the phone re-enumerates within ~1 s; longer: start over */
#define AOA_PIPE_ERRORS 8u      /* consecutive bulk errors (not NAKs) before the device is enumerated again,
                                   or refused if the last was a STALL (AOA_EV_STALLED) */
#define AOA_CLEAR_TRIES 3u      /* CLEAR_FEATURE(ENDPOINT_HALT)s failed (NAKed to the control transfer's
                                   deadline, STALLed) since the device was plugged in, each followed by a
                                   re-enumeration, before it is refused (AOA_EV_STALLED); at most 3 (a 2-bit
                                   count) */
#define AOA_OUT_PER_POLL 4u     /* bulk OUT packets per poll */
#define AOA_HANDSHAKE_TRIES 3u  /* failed handshakes (bus errors, timeouts, START without a switch) before
                                   the device is refused */

typedef enum {
    AOA_IDLE = 0,    /* no configured device (one failing enumeration, or a dead chip, is said once:
                        AOA_EV_NO_ENUM, AOA_EV_NO_CHIP; the host stack keeps retrying) */
    AOA_HANDSHAKE,   /* GET_PROTOCOL, SEND_STRING x6, START in progress */
    AOA_WAIT_REENUM, /* START sent: waiting for the phone to come back as an accessory */
    AOA_RUNNING,     /* accessory mode: bytes flow */
    AOA_CLEAR_HALT,  /* a bulk endpoint STALLed: CLEAR_FEATURE(ENDPOINT_HALT) in progress */
    AOA_REFUSED,     /* the device has no (usable) accessory mode, or never switches to it: nothing until it
                        is unplugged (a new attach tries again) */
} aoa_state_t;

/* Events for the link layer's log (usb_link_event). */
enum {
    AOA_EV_UP = 1,    /* accessory pipes open (arg: product id) */
    AOA_EV_DOWN,      /* the accessory went away (detach or re-enumeration) */
    AOA_EV_NO_AOA,    /* the phone reports AOA protocol 0 (or STALLs GET_PROTOCOL): refused (arg: version) */
    AOA_EV_STARTED,   /* START sent (arg: the phone's AOA version) */
    AOA_EV_FAILED,    /* the handshake failed (arg: HRSL code) */
    AOA_EV_NO_PIPES,  /* an accessory-mode device without a bulk pair (audio-only product id) */
    AOA_EV_NO_SWITCH, /* START taken AOA_HANDSHAKE_TRIES times, the phone never came back as an accessory
                         (stayed, or came back in its normal mode): refused (arg: the phone's AOA version) */
    AOA_EV_NO_ENUM,   /* the device attached fails enumeration USB_ENUM_TRIES times (arg: the HRSL of the last
                         control transaction) */
    AOA_EV_NO_CHIP,   /* the MAX3421E's oscillator never came up (arg: 0) */
    AOA_EV_STALLED,   /* a bulk endpoint STALLed AOA_PIPE_ERRORS times in a row, cleared each time, nothing
                         moving between, or its CLEAR_FEATURE failed AOA_CLEAR_TRIES times (a re-enumeration
                         after each): refused until unplugged (arg: the endpoint address), after a DOWN */
    AOA_EV_BAD_DEVICE, /* the host stack refused the device for its device descriptor (USB_REFUSED: short, not
                          a device descriptor, or a bMaxPacketSize0 other than 8/16/32/64), until unplugged
                          (arg: bMaxPacketSize0; 0 also when the answer ended before it or was no device
                          descriptor: bLength not 18, bDescriptorType not 1) */
};

/* Provided by the link layer: the bytes waiting to go to the phone. */
uint16_t usb_tx_pending(void);
/* Copy up to `max` of the oldest waiting bytes to dst without removing them: the count copied. */
uint8_t usb_tx_peek(uint8_t *dst, uint8_t max);
void usb_tx_consume(uint8_t n);
/* Provided by the link layer: something to report (AOA_EV_*). */
void usb_link_event(uint8_t ev, uint16_t arg);

/* `serial`: the board's serial (RAM, NUL-terminated, kept): the sixth identity string. */
void aoa_init(const char *serial);
/* Host stack and accessory layer, one bounded pass. */
void aoa_poll(uint32_t now_us);
aoa_state_t aoa_state(void);
uint8_t aoa_read(uint8_t *b);
uint8_t aoa_rx_pending(void);
uint16_t aoa_protocol_version(void);
/* The event's log text into out (room for n bytes, NUL-terminated). */
void aoa_event_text(uint8_t ev, uint16_t arg, char *out, uint8_t n);

#endif /* AOA_H */
