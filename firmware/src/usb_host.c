/* usb_host.c - attach, reset, enumeration and the control/bulk transaction engine (see usb_host.h).
 * Portable: the chip through max3421e_drv.h, time through spi.h. */
#include "usb_host.h"

#include <string.h>

#include "flash.h"
#include "max3421e_drv.h"
#include "spi.h"

usb_device_t usb_dev;
usb_stats_t usb_stats;

#define REQ_GET_DESCRIPTOR 6u
#define REQ_SET_ADDRESS 5u
#define REQ_SET_CONFIGURATION 9u
#define DESC_DEVICE 1u
#define DESC_CONFIGURATION 2u
#define DESC_INTERFACE 4u
#define DESC_ENDPOINT 5u
#define CONFIG_MAX_LEN 512u /* the bulk pair is in the first interface: no need to read further */

static struct {
    uint8_t state, step, address;
    uint8_t tries : 7;
    uint8_t recovery_replug : 1; /* an attach event in a reset recovery was taken for a replug, since the
                                    last detach seen as such or configured device (bus_event); a bit of
                                    tries' byte: RAM leaves the stack its 1 KB */
    uint8_t generation; /* wraps: only compared for a change */
    uint32_t since_us; /* when the present state (or enumeration step) began */
} host;

/* ------------------------------------------------------------------------------- control transfers */
enum { CTL_SETUP, CTL_DATA_IN, CTL_DATA_OUT, CTL_STATUS_IN, CTL_STATUS_OUT, CTL_DONE, CTL_FAILED };

static struct {
    uint8_t setup[8];
    uint8_t stage, out_flash, hr, retry_out;
    uint16_t left, done;
    const uint8_t *out;
    usb_in_sink_t sink;
    uint32_t started_us;
} ctl;

void usb_ctl_start(const usb_setup_t *s, const uint8_t *out, uint8_t out_flash, usb_in_sink_t sink)
{
    ctl.setup[0] = s->bmRequestType;
    ctl.setup[1] = s->bRequest;
    ctl.setup[2] = (uint8_t)s->wValue;
    ctl.setup[3] = (uint8_t)(s->wValue >> 8);
    ctl.setup[4] = (uint8_t)s->wIndex;
    ctl.setup[5] = (uint8_t)(s->wIndex >> 8);
    ctl.setup[6] = (uint8_t)s->wLength;
    ctl.setup[7] = (uint8_t)(s->wLength >> 8);
    ctl.left = s->wLength;
    ctl.done = 0;
    ctl.out = out;
    ctl.out_flash = out_flash;
    ctl.sink = sink;
    ctl.stage = CTL_SETUP;
    ctl.hr = MAX_HR_SUCCESS;
    ctl.retry_out = 0;
    ctl.started_us = usb_now_us();
}

uint8_t usb_ctl_result_hr(void) { return ctl.hr; }

/* Load an OUT packet into SNDFIFO. After a NAK the chip has handed the buffer to the bus engine: the
 * byte count is zeroed and the whole packet written again (USB Host Shield's documented re-load). */
static void load_out(const uint8_t *src, uint8_t n, uint8_t retry)
{
    if (retry)
        max_write(MAX_SNDBC, 0);
    max_write_fifo(MAX_SNDFIFO, src, n);
    max_write(MAX_SNDBC, n);
}

/* One transaction of the present stage: 1 to go on with another now, 0 to come back on the next poll. */
static uint8_t ctl_step(void)
{
    uint8_t hr, buf[64];
    switch (ctl.stage) {
    case CTL_SETUP:
        max_write(MAX_PERADDR, host.address);
        max_write_fifo(MAX_SUDFIFO, ctl.setup, 8);
        hr = max_xfer(MAX_TOK_SETUP);
        if (hr == MAX_HR_SUCCESS) {
            if (!ctl.left) {
                ctl.stage = CTL_STATUS_IN;
            } else if (ctl.setup[0] & 0x80u) {
                max_write(MAX_HCTL, MAX_RCVTOG1); /* the data stage starts with DATA1 */
                ctl.stage = CTL_DATA_IN;
            } else {
                max_write(MAX_HCTL, MAX_SNDTOG1);
                ctl.stage = CTL_DATA_OUT;
            }
            return 1;
        }
        break;
    case CTL_DATA_IN:
        hr = max_xfer(MAX_TOK_IN);
        if (hr == MAX_HR_SUCCESS) {
            uint8_t n = max_read(MAX_RCVBC);
            if (n > sizeof buf)
                n = sizeof buf; /* a babbling device: the chip's FIFO is 64 bytes anyway */
            max_read_fifo(MAX_RCVFIFO, buf, n);
            max_write(MAX_HIRQ, MAX_RCVDAVIRQ); /* frees the receive buffer */
            uint8_t take = n > ctl.left ? (uint8_t)ctl.left : n;
            if (ctl.sink && take)
                ctl.sink(buf, take);
            ctl.left = (uint16_t)(ctl.left - take);
            if (n < usb_dev.max_packet0 || !ctl.left)
                ctl.stage = CTL_STATUS_OUT; /* a short packet or all asked for: the data stage is over */
            return 1;
        }
        break;
    case CTL_DATA_OUT: {
        uint8_t n = ctl.left > usb_dev.max_packet0 ? usb_dev.max_packet0 : (uint8_t)ctl.left;
        if (ctl.out_flash)
            flash_read(buf, ctl.out + ctl.done, n);
        else
            for (uint8_t i = 0; i < n; i++)
                buf[i] = ctl.out[ctl.done + i];
        load_out(buf, n, ctl.retry_out);
        hr = max_xfer(MAX_TOK_OUT);
        ctl.retry_out = hr != MAX_HR_SUCCESS;
        if (hr == MAX_HR_SUCCESS) {
            ctl.done = (uint16_t)(ctl.done + n);
            ctl.left = (uint16_t)(ctl.left - n);
            if (!ctl.left)
                ctl.stage = CTL_STATUS_IN;
            return 1;
        }
        break;
    }
    case CTL_STATUS_IN:
        hr = max_xfer(MAX_TOK_IN_HS | 0u);
        if (hr == MAX_HR_SUCCESS) {
            ctl.stage = CTL_DONE;
            return 0;
        }
        break;
    case CTL_STATUS_OUT:
        hr = max_xfer(MAX_TOK_OUT_HS | 0u);
        if (hr == MAX_HR_SUCCESS) {
            ctl.stage = CTL_DONE;
            return 0;
        }
        break;
    default:
        return 0;
    }
    ctl.hr = hr;
    if (hr == MAX_HR_NAK) {
        usb_stats.naks_ridden++;
        return 0; /* the device is busy: ask again on the next poll */
    }
    usb_stats.last_hr = hr;
    if (hr == MAX_HR_STALL) {
        usb_stats.stalls++;
        ctl.stage = CTL_FAILED; /* a request error: endpoint 0 clears its STALL at the next SETUP */
        return 0;
    }
    usb_stats.xfer_errors++;
    return 0; /* a bus error (timeout, toggle, CRC): the same transaction again, until the deadline */
}

usb_ctl_result_t usb_ctl_poll(uint32_t now_us)
{
    for (uint8_t i = 0; i < USB_XFERS_PER_POLL && ctl.stage < CTL_DONE; i++)
        if (!ctl_step())
            break;
    if (ctl.stage == CTL_DONE)
        return USB_CTL_DONE;
    if (ctl.stage == CTL_FAILED)
        return USB_CTL_FAILED;
    if (now_us - ctl.started_us >= USB_CTL_TIMEOUT_US) {
        ctl.stage = CTL_FAILED;
        return USB_CTL_FAILED;
    }
    return USB_CTL_BUSY;
}

/* ------------------------------------------------------------------------------- bulk transactions */
uint8_t usb_bulk_in(uint8_t ep, uint8_t *toggle, uint8_t *n)
{
    max_write(MAX_PERADDR, host.address);
    max_write(MAX_HCTL, *toggle ? MAX_RCVTOG1 : MAX_RCVTOG0);
    uint8_t hr = max_xfer((uint8_t)(MAX_TOK_IN | ep));
    *n = 0;
    if (hr == MAX_HR_SUCCESS) {
        uint8_t c = max_read(MAX_RCVBC);
        *n = c > 64u ? 64u : c;
        *toggle = (max_read(MAX_HRSL) & MAX_RCVTOGRD) != 0; /* the chip flipped it on the good packet */
        if (!*n)
            max_write(MAX_HIRQ, MAX_RCVDAVIRQ); /* a zero-length packet: nothing to keep */
    } else if (hr == MAX_HR_STALL) {
        usb_stats.stalls++;
    } else if (hr != MAX_HR_NAK) {
        usb_stats.xfer_errors++;
    }
    if (hr != MAX_HR_SUCCESS && hr != MAX_HR_NAK)
        usb_stats.last_hr = hr;
    return hr;
}

uint8_t usb_bulk_out(uint8_t ep, uint8_t *toggle, const uint8_t *src, uint8_t n)
{
    max_write(MAX_PERADDR, host.address);
    max_write(MAX_HCTL, *toggle ? MAX_SNDTOG1 : MAX_SNDTOG0);
    load_out(src, n, 0);
    uint8_t hr = max_xfer((uint8_t)(MAX_TOK_OUT | ep));
    if (hr == MAX_HR_SUCCESS) {
        *toggle = (max_read(MAX_HRSL) & MAX_SNDTOGRD) != 0;
    } else {
        max_write(MAX_SNDBC, 0); /* take the packet back: the caller sends it again (or not) later */
        if (hr == MAX_HR_STALL)
            usb_stats.stalls++;
        else if (hr != MAX_HR_NAK)
            usb_stats.xfer_errors++;
        if (hr != MAX_HR_NAK)
            usb_stats.last_hr = hr;
    }
    return hr;
}

/* ------------------------------------------------------------------------------- enumeration */
/* The enumeration, one control transfer per step. */
enum { STEP_DEV8, STEP_SET_ADDRESS, STEP_ADDRESS_WAIT, STEP_DEV18, STEP_CONF9, STEP_CONF, STEP_SET_CONFIG, STEP_END };

/* The configuration descriptor arrives in packets: a small streaming parser keeps the bytes it needs
 * (configuration value, interface number, the bulk endpoints of interface 0's default setting) instead of
 * a buffer.
 * The device descriptor's reads use it too: its bLength and bDescriptorType land in len and type. */
static struct {
    uint16_t offset, total; /* bytes seen; wTotalLength */
    uint8_t pos, len, type, iface; /* pos: the byte of the present descriptor next (PARSE_MALFORMED: stopped) */
    uint8_t field[4]; /* the descriptor's bytes 2..5 */
} parse;

/* parse.pos once a descriptor was found malformed: nothing after it is read (a descriptor's pos is at most
 * 254 between bytes, since bLength <= 255). A byte rather than a flag: the board's RAM is full. */
#define PARSE_MALFORMED 0xFFu

static void device_sink(const uint8_t *d, uint8_t n)
{
    for (uint8_t i = 0; i < n; i++, parse.offset++) {
        uint16_t at = parse.offset;
        if (at == 0)
            parse.len = d[i]; /* bLength and bDescriptorType: device_descriptor_ok() judges them */
        else if (at == 1)
            parse.type = d[i];
        else if (at == 7)
            usb_dev.max_packet0 = d[i]; /* as said: device_descriptor_ok() judges it once the read is done */
        else if (at == 8)
            usb_dev.vid = d[i];
        else if (at == 9)
            usb_dev.vid |= (uint16_t)(d[i] << 8);
        else if (at == 10)
            usb_dev.pid = d[i];
        else if (at == 11)
            usb_dev.pid |= (uint16_t)(d[i] << 8);
    }
}

/* The standard size of a descriptor of `type` (USB 2.0 9.6.3, 9.6.5, 9.6.6), bytes: one shorter ends
 * before its fields do, and what they would be read from is the descriptor before it. Types the parser
 * does not read (class-specific, interface association, ...) need only their own two header bytes. */
static uint8_t standard_length(uint8_t type)
{
    if (type == DESC_CONFIGURATION || type == DESC_INTERFACE)
        return 9u;
    return type == DESC_ENDPOINT ? 7u : 2u;
}

/* The standard fields of the present descriptor (its bytes 2..5 in parse.field) are all in: take them. */
static void descriptor_fields_in(void)
{
    if (parse.type == DESC_CONFIGURATION) {
        if (parse.offset != 8u)
            return; /* one further in the answer is not this configuration's: skipped (USB 2.0 9.4.3) */
        parse.total = (uint16_t)(parse.field[0] | parse.field[1] << 8);
        usb_dev.config_value = parse.field[3];
    } else if (parse.type == DESC_INTERFACE) {
        /* an alternate setting other than 0 (bAlternateSetting, byte 3) is not the one SET_CONFIGURATION
         * selects, and the host asks for no other: its endpoints are not active, not the bulk pair's */
        parse.iface = parse.field[1] ? 0xFFu : parse.field[0];
    } else if (parse.type == DESC_ENDPOINT && parse.iface == 0 && (parse.field[1] & 3u) == 2u) {
        uint8_t ep = parse.field[0] & 0x0Fu;
        uint8_t mps = parse.field[3] ? 64u : (parse.field[2] > 64u ? 64u : parse.field[2]);
        if ((parse.field[0] & 0x80u) && !usb_dev.bulk_in) {
            usb_dev.bulk_in = ep;
            usb_dev.in_packet = mps;
        } else if (!(parse.field[0] & 0x80u) && !usb_dev.bulk_out) {
            usb_dev.bulk_out = ep;
            usb_dev.out_packet = mps;
        }
    }
}

/* A descriptor is judged as soon as its header is in: a bLength below its type's standard size (0 and 1
 * included) marks the answer malformed and the rest unread - its fields would be the last descriptor's
 * bytes, and the bytes after it no descriptor boundary anyone said. Its fields are taken once its standard
 * part is in (a longer bLength, as USB allows, skips the rest); the caller refuses a malformed answer and
 * one that ends inside a descriptor (enumerate()). */
static void config_sink(const uint8_t *d, uint8_t n)
{
    for (uint8_t i = 0; i < n && parse.pos != PARSE_MALFORMED; i++, parse.offset++) {
        uint8_t at = parse.pos++;
        if (at == 0) {
            parse.len = d[i];
            continue; /* its size is judged with its type, the next byte */
        }
        if (at == 1) {
            parse.type = d[i];
            if (parse.len < standard_length(parse.type)) {
                parse.pos = PARSE_MALFORMED;
                return;
            }
        } else if (at < 6u) {
            parse.field[at - 2u] = d[i];
        }
        if (parse.pos == standard_length(parse.type))
            descriptor_fields_in();
        if (parse.pos == parse.len)
            parse.pos = 0; /* complete: the next byte starts the next descriptor */
    }
}

/* The device descriptor read (`asked` bytes of it) is one a host may go on with: all of it came (a device
 * descriptor is 18 bytes; a shorter answer leaves the VID/PID or the packet size unsaid), it says it is a
 * device descriptor (bLength 18, bDescriptorType 1: anything else is not one, whatever its byte 7), and
 * bMaxPacketSize0 is one full speed allows (USB 2.0 9.6.1: 8, 16, 32 or 64). Any other size would split
 * every control transfer at a boundary the device does not use - its short-packet ends misread, its OUT
 * data cut wrong - so the device is refused rather than guessed at. */
static uint8_t device_descriptor_ok(uint16_t asked)
{
    uint8_t mps = usb_dev.max_packet0;
    return parse.offset >= asked && parse.len == 18u && parse.type == DESC_DEVICE &&
           (mps == 8u || mps == 16u || mps == 32u || mps == 64u);
}

/* The configuration descriptor's answer to the step just done is one to configure by: at least the
 * configuration descriptor itself came, saying wTotalLength >= 9 and a bConfigurationValue other than 0
 * (SET_CONFIGURATION takes 0 as "unconfigure": the device would stay in its address state, its bulk
 * endpoints unanswered, and be taken for configured); no descriptor in it is shorter than its standard
 * size; and the full read ends on a descriptor's end - unless the end is the host's own CONFIG_MAX_LEN (a
 * wTotalLength past it is read that far). An answer shorter than wTotalLength that ends on one is taken, as
 * other hosts do: what came is whole. */
static uint8_t config_descriptor_ok(uint8_t step)
{
    if (parse.pos == PARSE_MALFORMED || parse.offset < 9u || parse.total < 9u || !usb_dev.config_value)
        return 0;
    return step == STEP_CONF9 || !parse.pos || parse.total > CONFIG_MAX_LEN;
}

static void enter(uint8_t state, uint32_t now_us)
{
    host.state = state;
    host.since_us = now_us;
}

static void start_step(uint8_t step, uint32_t now_us)
{
    host.step = step;
    host.since_us = now_us;
    usb_setup_t s;
    s.bmRequestType = 0x80u; /* IN, standard, device */
    s.bRequest = REQ_GET_DESCRIPTOR;
    s.wValue = (uint16_t)(DESC_DEVICE << 8);
    s.wIndex = 0;
    s.wLength = 8;
    usb_in_sink_t sink = device_sink;
    parse.offset = 0;
    switch (step) {
    case STEP_DEV8:
        usb_dev.max_packet0 = 8; /* until the device says: every device takes 8-byte packets on EP0 */
        break;
    case STEP_SET_ADDRESS:
        s.bmRequestType = 0x00u;
        s.bRequest = REQ_SET_ADDRESS;
        s.wValue = USB_DEVICE_ADDRESS;
        s.wLength = 0;
        sink = 0;
        break;
    case STEP_ADDRESS_WAIT:
        host.address = USB_DEVICE_ADDRESS;
        return; /* no transfer: the recovery interval */
    case STEP_DEV18:
        s.wLength = 18;
        break;
    case STEP_CONF9:
        /* what this read finds, or nothing: never the last device's length and value, which a descriptor
         * that does not complete in its 9 bytes (a bLength past them, another type) would leave standing */
        parse.total = 0;
        usb_dev.config_value = 0;
        /* fall through */
    case STEP_CONF:
        s.wValue = (uint16_t)(DESC_CONFIGURATION << 8);
        s.wLength = step == STEP_CONF9 ? 9u : (parse.total > CONFIG_MAX_LEN ? CONFIG_MAX_LEN : parse.total);
        parse.pos = 0;
        parse.iface = 0xFF;
        usb_dev.bulk_in = usb_dev.bulk_out = 0;
        sink = config_sink;
        break;
    case STEP_SET_CONFIG:
        s.bmRequestType = 0x00u;
        s.bRequest = REQ_SET_CONFIGURATION;
        s.wValue = usb_dev.config_value;
        s.wLength = 0;
        sink = 0;
        break;
    default:
        return;
    }
    usb_ctl_start(&s, 0, 0, sink);
}

static void start_reset(uint32_t now_us)
{
    host.address = 0;
    max_bus_reset();
    enter(USB_RESETTING, now_us);
}

static void enum_failed(uint32_t now_us)
{
    usb_stats.enum_failures++;
    if (++host.tries < USB_ENUM_TRIES)
        start_reset(now_us);
    else
        enter(USB_ERROR, now_us);
}

static void enumerate(uint32_t now_us)
{
    if (host.step == STEP_ADDRESS_WAIT) {
        if (now_us - host.since_us >= USB_SET_ADDRESS_US)
            start_step(STEP_DEV18, now_us);
        return;
    }
    usb_ctl_result_t r = usb_ctl_poll(now_us);
    if (r == USB_CTL_BUSY)
        return;
    if (r == USB_CTL_FAILED) {
        enum_failed(now_us);
        return;
    }
    if ((host.step == STEP_DEV8 || host.step == STEP_DEV18) &&
        !device_descriptor_ok(host.step == STEP_DEV8 ? 8u : 18u)) {
        /* no retry: the same device answers the same descriptor; counted, said by the accessory layer */
        if (parse.offset < 8u || parse.len != 18u || parse.type != DESC_DEVICE)
            usb_dev.max_packet0 = 0; /* the answer ended before it, or is no device descriptor to say it */
        if (usb_stats.refused < 0xFFu)
            usb_stats.refused++;
        enter(USB_REFUSED, now_us);
        return;
    }
    if ((host.step == STEP_CONF9 || host.step == STEP_CONF) && !config_descriptor_ok(host.step)) {
        /* no usable configuration descriptor (config_descriptor_ok): never configured by stale or unsaid
         * fields, nor with a bConfigurationValue that leaves it unconfigured - up and down again every few
         * passes; a counted failure, retried and said once (AOA_EV_NO_ENUM) as any failed enumeration */
        enum_failed(now_us);
        return;
    }
    if (host.step == STEP_SET_CONFIG) {
        host.tries = 0;
        host.recovery_replug = 0;
        enter(USB_CONFIGURED, now_us);
        return;
    }
    start_step((uint8_t)(host.step + 1u), now_us);
}

/* ------------------------------------------------------------------------------- attach, detach */
void usb_host_init(void)
{
    spi_init();
    memset(&host, 0, sizeof host);
    memset(&ctl, 0, sizeof ctl);
    memset(&parse, 0, sizeof parse);
    memset(&usb_dev, 0, sizeof usb_dev);
    max_chip_reset();
    enter(USB_OSC_WAIT, usb_now_us());
}

usb_state_t usb_host_state(void) { return (usb_state_t)host.state; }

uint8_t usb_host_generation(void) { return host.generation; }

void usb_host_reenumerate(void)
{
    host.tries = 0;
    start_reset(usb_now_us());
}

static void detached(uint32_t now_us)
{
    if (host.state >= USB_SETTLE) {
        usb_stats.detaches++;
        host.generation++;
    }
    host.address = 0;
    memset(&usb_dev, 0, sizeof usb_dev);
    max_write(MAX_MODE, MAX_DPPULLDN | MAX_DMPULLDN | MAX_HOST); /* no SOFs to an empty port */
    enter(USB_DETACHED, now_us);
}

/* A connect/disconnect event (CONDETIRQ, seen on INT): the bus's J/K now says attached or not. */
static void bus_event(uint32_t now_us)
{
    if (host.state == USB_RESETTING)
        return; /* the reset itself drives SE0: the event is left pending and judged when the reset ends */
    max_write(MAX_HIRQ, MAX_CONDETIRQ);
    max_bus_t bus = max_sample_bus();
    if (bus == MAX_BUS_SE0 || bus == MAX_BUS_SE1) {
        host.recovery_replug = 0;
        if (host.state != USB_DETACHED)
            detached(now_us);
        return;
    }
    /* Attached now, yet the port saw a change: unplugged and plugged back between two looks, so what is
     * there is a new device, powered but never reset: it answers nothing until a bus reset. In the reset
     * recovery too - the events of the reset itself (its SE0, its end) were cleared as it ended - or
     * the enumeration would go on at a device that is not listening (timeouts, then a retry ~0.5 s on).
     * Once per attach there: a chip raising CONDETIRQ a little after its reset ends (after the driver's
     * clear) would otherwise be taken for a replug at every reset, debounced and reset again for ever. */
    if (host.state == USB_RESET_RECOVERY) {
        if (host.recovery_replug)
            return; /* taken for the reset's own end */
        host.recovery_replug = 1;
    }
    if (host.state != USB_DETACHED)
        detached(now_us);
    if (host.state == USB_DETACHED || host.state == USB_ERROR) {
        usb_stats.attaches++;
        host.generation++;
        host.tries = 0;
        usb_dev.low_speed = bus == MAX_BUS_LOW;
        enter(USB_SETTLE, now_us);
    }
}

void usb_host_poll(uint32_t now_us)
{
    uint32_t in_state = now_us - host.since_us;
    switch (host.state) {
    case USB_OFF:
        return;
    case USB_OSC_WAIT:
        if (max_osc_ok()) {
            max_host_mode();
            enter(USB_DETACHED, now_us);
            bus_event(now_us); /* a device already plugged in at power-up raised no event */
        } else if (in_state >= USB_OSC_MAX_US) {
            enter(USB_CHIP_DEAD, now_us);
        }
        return;
    case USB_CHIP_DEAD:
        if (in_state >= USB_RETRY_US) {
            usb_reset_pin(1);
            usb_reset_pin(0);
            max_chip_reset();
            enter(USB_OSC_WAIT, now_us);
        }
        return;
    default:
        break;
    }
    if (usb_int_asserted())
        bus_event(now_us);
    switch (host.state) {
    case USB_SETTLE:
        if (in_state >= USB_DEBOUNCE_US)
            start_reset(now_us);
        break;
    case USB_RESETTING:
        if (max_bus_reset_done()) {
            /* A connect event latched now came during the reset or in the moments since it ended, before
             * this look (the main loop busy elsewhere): a phone plugged back there was never reset (or not
             * for long enough) and answers nothing until it is - taken for the reset's own, it was
             * enumerated blind to the control transfer's deadline, then retried. It is judged as one in the
             * reset recovery is: a replug, once per attach (a chip that raises the event for its own reset
             * costs one more debounce and reset, not a loop). */
            uint8_t event = max_read(MAX_HIRQ) & MAX_CONDETIRQ;
            max_write(MAX_HIRQ, MAX_CONDETIRQ);
            max_bus_t bus = max_sample_bus();
            if (bus == MAX_BUS_SE0 || bus == MAX_BUS_SE1) {
                detached(now_us); /* unplugged during the reset */
                break;
            }
            max_set_speed(usb_dev.low_speed ? MAX_BUS_LOW : MAX_BUS_FULL);
            enter(USB_RESET_RECOVERY, now_us);
            if (event)
                bus_event(now_us);
        } else if (in_state >= USB_RESET_MAX_US) {
            enum_failed(now_us);
        }
        break;
    case USB_RESET_RECOVERY:
        if (in_state >= USB_RECOVERY_US) {
            enter(USB_ENUMERATING, now_us);
            start_step(STEP_DEV8, now_us);
        }
        break;
    case USB_ENUMERATING:
        enumerate(now_us);
        break;
    case USB_ERROR:
        if (in_state >= USB_RETRY_US) {
            host.tries = 0;
            start_reset(now_us);
        }
        break;
    default:
        break;
    }
}
