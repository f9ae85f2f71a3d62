/* aoa.c - Android Open Accessory over the USB host stack (see aoa.h). Portable. */
#include "aoa.h"

#include <string.h>

#include "board_gen.h"
#include "flash.h"
#include "max3421e_drv.h"
#include "usb_host.h"

static const char S_MANUFACTURER[] FLASH = IDENTITY_MANUFACTURER;
static const char S_MODEL[] FLASH = IDENTITY_MODEL;
static const char S_DESCRIPTION[] FLASH = IDENTITY_DESCRIPTION;
static const char S_VERSION[] FLASH = IDENTITY_VERSION;
static const char S_URI[] FLASH = IDENTITY_URI;

/* Identity string `index` (0..4, in flash). A switch, not a table: a table of pointers would sit in RAM. */
static const char *identity_string(uint8_t index)
{
    switch (index) {
    case 0:
        return S_MANUFACTURER;
    case 1:
        return S_MODEL;
    case 2:
        return S_DESCRIPTION;
    case 3:
        return S_VERSION;
    default:
        return S_URI;
    }
}

static struct {
    uint8_t state, step; /* step: 0 GET_PROTOCOL, 1..6 SEND_STRING index step-1, 7 START */
    uint8_t in_toggle, out_toggle, zlp_due;
    uint8_t errors : 4; /* RUNNING: consecutive bulk errors; before: failed handshakes with this device */
    uint8_t clear_fails : 2; /* CLEAR_FEATUREs (ENDPOINT_HALT) that failed since this device was plugged in:
                                re-enumerations do not reset it (a bit-field: RAM leaves the stack its 1 KB) */
    uint8_t halted_ep; /* CLEAR_HALT: the endpoint; HANDSHAKE: STALLs of GET_PROTOCOL; IDLE: the host
                          stack's failure (no enumeration, no chip) has been said */
    uint8_t rx_left; /* bytes of the last bulk IN packet still in the chip's RCVFIFO (the receive buffer) */
    uint8_t out_resend; /* bytes of a bulk OUT packet that got no handshake (a bus error: the phone may have
                           taken it, its ACK lost), to go again exactly; OUT_RESEND_NONE: none */
    uint16_t version;
    uint8_t generation, start_generation; /* usb_host_generation(); the one START was sent in */
    uint32_t since_us;
    const char *serial;
} aoa;

_Static_assert(AOA_PIPE_ERRORS < 16u && AOA_HANDSHAKE_TRIES < 16u && AOA_CLEAR_TRIES < 4u,
               "aoa.errors and aoa.clear_fails are bit-fields of 4 and 2 bits");

/* aoa.out_resend with no packet waiting to be sent again (a real one is at most 64 bytes). */
#define OUT_RESEND_NONE 0xFFu

void aoa_init(const char *serial)
{
    memset(&aoa, 0, sizeof aoa);
    aoa.out_resend = OUT_RESEND_NONE;
    aoa.serial = serial;
    usb_host_init();
    aoa.generation = usb_host_generation();
}

aoa_state_t aoa_state(void) { return (aoa_state_t)aoa.state; }

uint16_t aoa_protocol_version(void) { return aoa.version; }

uint8_t aoa_rx_pending(void) { return aoa.rx_left != 0; }

/* The packet stays in the MAX3421E's RCVFIFO and is read a byte at a time as the deframer takes it:
 * the chip's 64-byte FIFO is the receive buffer (~3 us of SPI a byte instead of 64 bytes of RAM). */
uint8_t aoa_read(uint8_t *b)
{
    if (!aoa.rx_left)
        return 0;
    *b = max_read(MAX_RCVFIFO);
    if (!--aoa.rx_left)
        max_write(MAX_HIRQ, MAX_RCVDAVIRQ); /* read out: the buffer is the chip's again */
    return 1;
}

/* Drop what is left of a received packet (the device went away or is enumerated again). */
static void rx_drop(void)
{
    if (aoa.rx_left)
        max_write(MAX_HIRQ, MAX_RCVDAVIRQ);
    aoa.rx_left = 0;
}

static void version_sink(const uint8_t *d, uint8_t n)
{
    if (n >= 1)
        aoa.version = d[0];
    if (n >= 2)
        aoa.version |= (uint16_t)(d[1] << 8);
}

static uint16_t flash_len(const char *s)
{
    uint16_t n = 0;
    while (flash_byte(s + n))
        n++;
    return n;
}

/* Start the handshake's request number `step`. */
static void handshake_step(uint8_t step)
{
    usb_setup_t s;
    s.bmRequestType = 0x40u; /* OUT, vendor, device */
    s.wValue = s.wIndex = s.wLength = 0;
    aoa.step = step;
    if (step == 0) {
        s.bmRequestType = 0xC0u; /* IN, vendor, device */
        s.bRequest = AOA_REQ_GET_PROTOCOL;
        s.wLength = 2;
        aoa.version = 0;
        usb_ctl_start(&s, 0, 0, version_sink);
    } else if (step <= AOA_STRINGS) {
        uint8_t index = (uint8_t)(step - 1u);
        uint8_t in_flash = index < 5u; /* the serial (index 5) is the board's, from its EEPROM */
        const char *text = in_flash ? identity_string(index) : aoa.serial;
        s.bRequest = AOA_REQ_SEND_STRING;
        s.wIndex = index;
        s.wLength = (uint16_t)((in_flash ? flash_len(text) : strlen(text)) + 1u); /* with the NUL */
        usb_ctl_start(&s, (const uint8_t *)text, in_flash, 0);
    } else {
        s.bRequest = AOA_REQ_START;
        usb_ctl_start(&s, 0, 0, 0);
    }
}

static void enter(uint8_t state, uint32_t now_us)
{
    aoa.state = state;
    aoa.since_us = now_us;
    if (state == AOA_IDLE)
        aoa.halted_ep = 0; /* its IDLE meaning from here: nothing said yet (CLEAR_HALT left its endpoint) */
}

static uint8_t is_accessory(void)
{
    return usb_dev.vid == AOA_GOOGLE_VID && usb_dev.pid >= AOA_PID_FIRST && usb_dev.pid <= AOA_PID_LAST;
}

/* START was taken and no accessory came of it: start over, a few times; then refuse the phone, as a
 * failed handshake is, until it is unplugged (no endless START loop). */
static void no_switch(uint32_t now_us)
{
    if (++aoa.errors >= AOA_HANDSHAKE_TRIES) {
        usb_link_event(AOA_EV_NO_SWITCH, aoa.version);
        enter(AOA_REFUSED, now_us);
        return;
    }
    enter(AOA_IDLE, now_us);
}

/* A configured device: an accessory already, or a phone to switch. */
static void device_ready(uint32_t now_us)
{
    aoa.halted_ep = 0; /* a device configured: a later failure of the host stack is news again */
    if (is_accessory()) {
        if (!usb_dev.bulk_in || !usb_dev.bulk_out || !usb_dev.in_packet || !usb_dev.out_packet) {
            usb_link_event(AOA_EV_NO_PIPES, usb_dev.pid);
            enter(AOA_REFUSED, now_us);
            return;
        }
        aoa.in_toggle = aoa.out_toggle = 0; /* SET_CONFIGURATION resets every data toggle */
        aoa.zlp_due = aoa.errors = 0;
        aoa.rx_left = 0;
        aoa.out_resend = OUT_RESEND_NONE;
        enter(AOA_RUNNING, now_us);
        usb_link_event(AOA_EV_UP, usb_dev.pid);
        return;
    }
    enter(AOA_HANDSHAKE, now_us);
    handshake_step(0);
}

static void handshake(uint32_t now_us)
{
    usb_ctl_result_t r = usb_ctl_poll(now_us);
    if (r == USB_CTL_BUSY)
        return;
    if (r == USB_CTL_FAILED) {
        uint8_t hr = usb_ctl_result_hr();
        if (aoa.step == 0 && hr == MAX_HR_STALL) {
            /* a STALLed vendor request is how a device without AOA answers; ep0's STALL clears at the next
             * SETUP, so ask once more before refusing (a single stray STALL is not a refusal) */
            if (!aoa.halted_ep++) {
                handshake_step(0);
                return;
            }
            usb_link_event(AOA_EV_NO_AOA, 0);
            enter(AOA_REFUSED, now_us);
            return;
        }
        usb_link_event(AOA_EV_FAILED, hr);
        if (++aoa.errors >= AOA_HANDSHAKE_TRIES) {
            enter(AOA_REFUSED, now_us); /* until it is unplugged: no endless retry against a broken phone */
            return;
        }
        enter(AOA_IDLE, now_us);
        usb_host_reenumerate(); /* a clean start: the next enumeration runs the handshake again */
        return;
    }
    if (aoa.step == 0) {
        aoa.halted_ep = 0;
        if (aoa.version == 0) {
            usb_link_event(AOA_EV_NO_AOA, 0);
            enter(AOA_REFUSED, now_us);
            return;
        }
    }
    if (aoa.step <= AOA_STRINGS) {
        handshake_step((uint8_t)(aoa.step + 1u));
        return;
    }
    usb_link_event(AOA_EV_STARTED, aoa.version);
    aoa.start_generation = aoa.generation;
    enter(AOA_WAIT_REENUM, now_us);
}

static void pipe_error(uint8_t hr, uint8_t ep_addr, uint32_t now_us)
{
    /* STALLs count too (a success resets the count): an endpoint that STALLs again after every
     * CLEAR_FEATURE, nothing moving between, was cleared for ever, without a word, the link dead */
    if (++aoa.errors >= AOA_PIPE_ERRORS) {
        aoa.errors = 0;
        rx_drop();
        if (hr == MAX_HR_STALL) {
            /* a halt the phone sets again at once: no enumeration mends it; refused until unplugged */
            usb_link_event(AOA_EV_DOWN, 0);
            usb_link_event(AOA_EV_STALLED, ep_addr);
            enter(AOA_REFUSED, now_us);
            return;
        }
        usb_host_reenumerate();
        return;
    }
    if (hr == MAX_HR_STALL) {
        /* CLEAR_FEATURE(ENDPOINT_HALT): the endpoint and its toggle start over at DATA0 */
        usb_setup_t s;
        s.bmRequestType = 0x02u; /* OUT, standard, endpoint */
        s.bRequest = 1u;         /* CLEAR_FEATURE */
        s.wValue = 0;            /* ENDPOINT_HALT */
        s.wIndex = ep_addr;
        s.wLength = 0;
        aoa.halted_ep = ep_addr;
        usb_ctl_start(&s, 0, 0, 0);
        enter(AOA_CLEAR_HALT, now_us);
    }
}

static void run_pipes(uint32_t now_us)
{
    if (!aoa.rx_left) {
        uint8_t n;
        uint8_t hr = usb_bulk_in(usb_dev.bulk_in, &aoa.in_toggle, &n);
        if (hr == MAX_HR_SUCCESS) {
            aoa.rx_left = n;
            aoa.errors = 0;
        } else if (hr != MAX_HR_NAK) { /* NAK: the phone has nothing for us */
            pipe_error(hr, (uint8_t)(0x80u | usb_dev.bulk_in), now_us);
            return;
        }
    }
    for (uint8_t k = 0; k < AOA_OUT_PER_POLL; k++) {
        uint8_t buf[64];
        uint8_t n = 0;
        if (aoa.out_resend != OUT_RESEND_NONE) {
            /* the very packet that got no handshake, not one grown by bytes queued since: if the phone took
             * it, it sees the same toggle again and discards the packet as a repeat - with it any new bytes */
            n = aoa.out_resend ? usb_tx_peek(buf, aoa.out_resend) : 0;
        } else if (usb_tx_pending()) {
            n = usb_tx_peek(buf, usb_dev.out_packet);
        } else if (!aoa.zlp_due) {
            return;
        }
        uint8_t hr = usb_bulk_out(usb_dev.bulk_out, &aoa.out_toggle, buf, n);
        if (hr != MAX_HR_SUCCESS) {
            if (hr == MAX_HR_NAK)
                return; /* the phone's buffer is full: the bytes (or the packet to resend) stay as they are */
            /* a STALLed packet was not taken, and the clear restarts the pipe at DATA0; after a bus error the
             * phone may hold it */
            aoa.out_resend = hr == MAX_HR_STALL ? OUT_RESEND_NONE : n;
            pipe_error(hr, usb_dev.bulk_out, now_us);
            return;
        }
        aoa.out_resend = OUT_RESEND_NONE;
        aoa.errors = 0;
        usb_tx_consume(n);
        aoa.zlp_due = n == usb_dev.out_packet && !usb_tx_pending();
    }
}

void aoa_poll(uint32_t now_us)
{
    usb_host_poll(now_us);
    uint8_t gen = usb_host_generation();
    if (gen != aoa.generation) { /* attached or detached since the last pass: what we had is gone */
        aoa.generation = gen;
        if (aoa.state == AOA_RUNNING || aoa.state == AOA_CLEAR_HALT)
            usb_link_event(AOA_EV_DOWN, 0);
        rx_drop(); /* a detach or a new device: free the chip's receive buffer for the next enumeration */
        aoa.halted_ep = 0;
        /* A new device starts with a clean slate - except the phone START was sent to, dropping off and
         * coming back (within AOA_REENUM_US): its failed switches go on counting, or a phone that comes
         * back in its normal mode every time would get START for ever. */
        if (aoa.state != AOA_WAIT_REENUM) {
            aoa.errors = 0;
            enter(AOA_IDLE, now_us);
        }
        aoa.clear_fails = 0; /* another device, or none: its halts are its own */
    }
    usb_state_t host_state = usb_host_state();
    if (host_state != USB_CONFIGURED) {
        rx_drop();
        if (aoa.state == AOA_RUNNING || aoa.state == AOA_CLEAR_HALT || aoa.state == AOA_HANDSHAKE) {
            usb_link_event(aoa.state == AOA_HANDSHAKE ? AOA_EV_FAILED : AOA_EV_DOWN, usb_stats.last_hr);
            enter(AOA_IDLE, now_us);
        } else if (aoa.state == AOA_WAIT_REENUM && now_us - aoa.since_us >= AOA_REENUM_US) {
            enter(AOA_IDLE, now_us);
        } else if (aoa.state == AOA_IDLE && !aoa.halted_ep &&
                   (host_state == USB_ERROR || host_state == USB_CHIP_DEAD || host_state == USB_REFUSED)) {
            /* the host stack retries (every USB_RETRY_US) without end, or has refused the device until it is
             * unplugged; said once, until a device is configured or another one is plugged in */
            if (host_state == USB_ERROR)
                usb_link_event(AOA_EV_NO_ENUM, usb_ctl_result_hr()); /* NAK (0x4): timed out on NAKs */
            else if (host_state == USB_REFUSED)
                usb_link_event(AOA_EV_BAD_DEVICE, usb_dev.max_packet0);
            else
                usb_link_event(AOA_EV_NO_CHIP, 0);
            aoa.halted_ep = 1;
        }
        return;
    }
    switch (aoa.state) {
    case AOA_WAIT_REENUM:
        if (aoa.generation == aoa.start_generation) { /* still the phone we sent START to: it drops off soon */
            if (now_us - aoa.since_us < AOA_REENUM_US)
                break;
            /* it never did (no accessory app, or AOA barred by policy) */
            no_switch(now_us);
            break;
        }
        if (!is_accessory()) { /* it dropped off and came back, not as an accessory: START failed again */
            no_switch(now_us);
            if (aoa.state == AOA_REFUSED)
                break;
        }
        device_ready(now_us);
        break;
    case AOA_IDLE:
        device_ready(now_us);
        break;
    case AOA_HANDSHAKE:
        handshake(now_us);
        break;
    case AOA_RUNNING:
        run_pipes(now_us);
        break;
    case AOA_CLEAR_HALT: {
        usb_ctl_result_t r = usb_ctl_poll(now_us);
        if (r == USB_CTL_BUSY)
            break;
        if (r == USB_CTL_FAILED) {
            rx_drop();
            /* The clear NAKed to its deadline (or failed): a re-enumeration resets the endpoint, but a phone
             * that halts it again and never takes the clear was re-enumerated for ever, ~0.6 s a round, the
             * link dead and nothing said; after AOA_CLEAR_TRIES of them it is refused until unplugged. */
            if (++aoa.clear_fails >= AOA_CLEAR_TRIES) {
                usb_link_event(AOA_EV_DOWN, 0);
                usb_link_event(AOA_EV_STALLED, aoa.halted_ep);
                enter(AOA_REFUSED, now_us);
                break;
            }
            usb_host_reenumerate();
            break;
        }
        aoa.clear_fails = 0; /* the halt cleared as USB says: the next one starts a new count */
        if (aoa.halted_ep & 0x80u)
            aoa.in_toggle = 0;
        else
            aoa.out_toggle = 0;
        aoa.halted_ep = 0;
        enter(AOA_RUNNING, now_us);
        break;
    }
    default: /* AOA_REFUSED: until the device goes away */
        break;
    }
}

/* ------------------------------------------------------------------------------- log texts */
static const char TEXTS[] FLASH = "\0"
                                  "USB accessory connected, product 0x\0"
                                  "USB accessory disconnected\0"
                                  "USB device refused: no Android accessory mode (AOA protocol 0)\0"
                                  "USB phone switching to accessory mode, AOA protocol \0"
                                  "USB accessory handshake failed, HRSL 0x\0"
                                  "USB accessory without a bulk pair refused, product 0x\0"
                                  "USB phone refused: no accessory mode after START, AOA protocol \0"
                                  "USB device not enumerated, retrying every second; last HRSL 0x\0"
                                  "USB host chip (MAX3421E) not responding, retrying every second\0"
                                  "USB accessory refused: its bulk endpoint keeps stalling, 0x\0"
                                  "USB device refused: bad device descriptor, bMaxPacketSize0 0x\0";

void aoa_event_text(uint8_t ev, uint16_t arg, char *out, uint8_t n)
{
    if (!n)
        return;
    flash_pick(TEXTS, ev <= AOA_EV_BAD_DEVICE ? ev : 0u, out, n);
    if (ev != AOA_EV_UP && ev != AOA_EV_STARTED && ev != AOA_EV_FAILED && ev != AOA_EV_NO_PIPES &&
        ev != AOA_EV_NO_SWITCH && ev != AOA_EV_NO_ENUM && ev != AOA_EV_STALLED && ev != AOA_EV_BAD_DEVICE)
        return;
    uint8_t at = (uint8_t)strlen(out);
    char digits[5];
    uint8_t k = 0;
    uint8_t hex = ev != AOA_EV_STARTED && ev != AOA_EV_NO_SWITCH;
    do {
        uint8_t d = (uint8_t)(hex ? arg % 16u : arg % 10u);
        digits[k++] = (char)(d < 10u ? (unsigned)'0' + d : (unsigned)'a' + d - 10u);
        arg = (uint16_t)(hex ? arg / 16u : arg / 10u);
    } while (arg && k < sizeof digits);
    while (k && at + 1u < n)
        out[at++] = digits[--k];
    out[at] = 0;
}
