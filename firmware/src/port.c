/* port.c - the byte link to the host: UART0, USB (AOA) or the first to speak (see port.h). */
#include "port.h"

#include <avr/pgmspace.h>

#include "aoa.h"
#include "app.h"
#include "clock.h"
#include "spi.h"
#include "uart.h"

static struct {
    uint8_t mode;   /* LINK_UART, LINK_USB or LINK_FIRST as configured */
    uint8_t active; /* the link chosen (LINK_FIRST: not yet) */
    uint8_t source; /* with LINK_FIRST: LINK_UART or LINK_USB, the link bytes are read from now */
    union {         /* RAM is tight: each half is used only while `active` says so */
        struct {    /* active == LINK_FIRST */
            uint8_t boundary; /* the last byte read from `source` ended a frame (or none was read) */
            uint16_t last_byte_ms; /* low 16 bits of clock_ms(): only differences < PORT_SWITCH_MS count */
        } first;
        struct {            /* active == LINK_USB: since the last note (port_poll), no accessory being open */
            uint8_t lost;   /* frames that found the ring full, or cut at a detach (saturating: LOST_MAX) */
            uint16_t stale; /* Telemetry/Heartbeat not queued (port_holds_reports) or dropped from the ring
                               (saturating: STALE_MAX) */
        } usb;
    } u;
} port;

void port_init(const board_config_t *cfg)
{
    port.mode = port.active = cfg->link;
    port.source = LINK_UART;
    port.u.first.boundary = cfg->link == LINK_FIRST; /* with LINK_USB: no frame lost, none stale yet */
    if (cfg->link != LINK_USB)
        uart_init(cfg->baud);
    else
        uart_hand_over(); /* UART0 stays off; its transmit ring is the USB link's queue */
    if (cfg->link != LINK_UART)
        aoa_init(cfg->serial);
    /* A reset (button, watchdog, brown-out) while a frame was going out left the host holding its start:
     * a lone delimiter first ends it as one bad frame (docs/protocol.md: idle fill), where the boot Log
     * with the reset cause was joined to it and lost. */
    const uint8_t delimiter = 0x00;
    uart_send(&delimiter, 1);
}

uint8_t port_active(void) { return port.active; }

static uint8_t usb_bytes(void) { return port.mode != LINK_UART && aoa_rx_pending(); }

static uint8_t accessory_open(void)
{
    aoa_state_t s = aoa_state();
    return s == AOA_RUNNING || s == AOA_CLEAR_HALT;
}

#define LOST_MAX 0xFFu     /* port.u.usb.lost's ceiling */
#define STALE_MAX 0xFFFFu  /* port.u.usb.stale's ceiling */

static const char AT_LEAST[] PROGMEM = "at least ";

/* The prefix of a count in a Log (a flash string, for %S): "at least " once it has reached its ceiling. */
static PGM_P bound(uint8_t saturated) { return saturated ? AT_LEAST : AT_LEAST + sizeof AT_LEAST - 1u; }

/* The link is USB and no accessory is open: what is queued waits for a phone that may come back. */
static uint8_t away(void) { return port.active == LINK_USB && !accessory_open(); }

void port_poll(void)
{
    if (port.mode == LINK_UART || port.active == LINK_UART) /* "first" won by UART0: USB rests */
        return;
    aoa_poll(usb_now_us());
    /* Once an accessory is open (again), what the phone did not get while none was: said once, after the
     * Logs made meanwhile; with room for the Log (else a later pass: the ring drains to the phone). */
    if (port.active == LINK_USB && (port.u.usb.stale || port.u.usb.lost) && accessory_open() &&
        uart_tx_free() >= PORT_NOTE_ROOM) {
        /* a count that reached its ceiling stopped counting: said as a bound, never as the number */
        report_log(port.u.usb.lost ? SEVERITY_WARNING : SEVERITY_INFO, LOG_CODE_STATE,
                   PSTR("while no USB accessory was open: %S%u telemetry/heartbeat frames not sent (stale), "
                        "%S%u other frames lost (transmit queue full, or cut at the detach)"),
                   bound(port.u.usb.stale == STALE_MAX), port.u.usb.stale, bound(port.u.usb.lost == LOST_MAX),
                   port.u.usb.lost);
        port.u.usb.stale = port.u.usb.lost = 0;
    }
}

static uint8_t read_from(uint8_t source, uint8_t *b)
{
    return source == LINK_USB ? aoa_read(b) : uart_read(b);
}

uint8_t port_read(uint8_t *b)
{
    if (port.active != LINK_FIRST)
        return read_from(port.active, b);
    uint16_t now = (uint16_t)clock_ms();
    if (!read_from(port.source, b)) {
        uint8_t other = port.source == LINK_UART ? LINK_USB : LINK_UART;
        uint8_t waiting = other == LINK_USB ? usb_bytes() : uart_rx_pending();
        if (!waiting ||
            (!port.u.first.boundary && (uint16_t)(now - port.u.first.last_byte_ms) < PORT_SWITCH_MS))
            return 0;
        port.source = other; /* at a frame boundary, or the source went silent in a frame */
        if (!read_from(port.source, b))
            return 0;
    }
    port.u.first.boundary = *b == 0x00;
    port.u.first.last_byte_ms = now;
    return 1;
}

uint8_t port_rx_pending(void)
{
    if (port.active == LINK_UART)
        return uart_rx_pending();
    if (port.active == LINK_USB)
        return aoa_rx_pending();
    return uart_rx_pending() || usb_bytes();
}

static void count_lost(void)
{
    if (port.u.usb.lost != LOST_MAX)
        port.u.usb.lost++;
}

static void count_stale(uint8_t n)
{
    uint16_t sum = (uint16_t)(port.u.usb.stale + n);
    port.u.usb.stale = sum < port.u.usb.stale ? STALE_MAX : sum;
}

uint8_t port_holds_reports(void)
{
    if (!away())
        return 0;
    count_stale(1);
    return 1;
}

uint8_t port_send(const uint8_t *data, uint16_t n)
{
    uint8_t sent = uart_send(data, n); /* the ring goes to TXD, or (USB) to the bulk OUT pipe */
    if (!sent && away())
        count_lost();
    return sent;
}

void port_frame_valid(void)
{
    if (port.active != LINK_FIRST)
        return;
    port.active = port.source;
    if (port.active == LINK_USB) {
        uart_hand_over(); /* UART0 is silent from now on: no "bytes lost" reports for a port nobody reads */
        port.u.usb.lost = 0;
        port.u.usb.stale = 0;
    }
}

/* ------------------------------------------------------------------ the USB stack's side (aoa.h) */
uint16_t usb_tx_pending(void) { return port.active == LINK_USB ? uart_tx_pending() : 0; }

uint8_t usb_tx_peek(uint8_t *dst, uint8_t max) { return uart_tx_peek(dst, max); }

void usb_tx_consume(uint8_t n) { uart_tx_consume(n); }

void usb_link_event(uint8_t ev, uint16_t arg)
{
    if (port.active == LINK_USB && (ev == AOA_EV_DOWN || ev == AOA_EV_UP)) {
        /* The phone went away, or one is back: the telemetry and heartbeats queued are stale (they would
         * reach the phone ahead of the Logs made meanwhile, shown as live); nothing else is dropped, the
         * event's own Log goes in after. At the re-open, what is left of a frame cut at the detach too. */
        uint8_t cut = 0;
        count_stale(uart_tx_drop_frames(MSG_TELEMETRY, MSG_HEARTBEAT, ev == AOA_EV_UP ? &cut : 0));
        if (cut)
            count_lost();
    }
    char text[72];
    aoa_event_text(ev, arg, text, sizeof text);
    uint8_t refused = ev == AOA_EV_NO_AOA || ev == AOA_EV_FAILED || ev == AOA_EV_NO_PIPES ||
                      ev == AOA_EV_NO_SWITCH || ev == AOA_EV_NO_ENUM || ev == AOA_EV_NO_CHIP ||
                      ev == AOA_EV_STALLED || ev == AOA_EV_BAD_DEVICE;
    uint8_t severity = refused ? SEVERITY_ERROR : (ev == AOA_EV_DOWN ? SEVERITY_WARNING : SEVERITY_INFO);
    report_log(severity, refused ? LOG_CODE_HANDSHAKE : LOG_CODE_STATE, PSTR("%s"), text);
}
