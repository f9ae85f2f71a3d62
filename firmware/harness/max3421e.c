/*
 * max3421e.c - the MAX3421E USB host controller, host mode, at register level, as seen over SPI.
 *
 * What is modelled (register names and bits as the Maxim datasheet and AN3785 define them):
 *  - SPI: the command byte rrrrr0d0 (d = 1: write); with PINCTL.FDUPSPI the byte clocked out during the
 *    command is HIRQ. Before FDUPSPI (half duplex, MISO unused) a read sees 0xFF and is reported in
 *    last_error. Repeated bytes go to the same register; the FIFOs advance their pointers.
 *  - Resets: the RES pin resets everything; USBCTL.CHIPRES everything but PINCTL and USBCTL. The oscillator
 *    restarts after either and USBIRQ.OSCOKIRQ rises OSC_START_US later.
 *  - Bus: HCTL.SAMPLEBUS copies the bus into HRSL.JSTATUS/KSTATUS (J for a full-speed device, SE0 with
 *    nothing attached) at once and reads back 1; HCTL.BUSRST drives SE0 for BUSRST_US, then clears itself
 *    and raises BUSEVENTIRQ; CONDETIRQ on attach and detach (host mode); with MODE.SOFKAENAB and a device
 *    attached, a SOF every 1 ms raises FRAMEIRQ.
 *  - Transfers: HXFR launches one transaction; it completes after its wire time (XFER_US plus the payload
 *    at 12 Mb/s) with HRSL's result code and HXFRDNIRQ. SETUP sends SUDFIFO's 8 bytes as DATA0 (from its start,
 *    where the CPU's next write starts too: a retry may rewrite them or not); IN loads
 *    one of RCVFIFO's two buffers (RCVBC, RCVDAVIRQ; writing RCVDAVIRQ frees the buffer and shows the next);
 *    OUT sends SNDFIFO's SNDBC bytes; HS-IN and HS-OUT are the control status stages (zero-length DATA1).
 *    RCVTOG/SNDTOG are set by HCTL's strobes, flip on each acknowledged data packet and read back in HRSL.
 *    An IN whose DATA PID differs from RCVTOG completes with hrTOGERR (the device, acknowledged, moves on).
 *    An OUT with the wrong toggle is acknowledged and discarded by the device (a repeat, to it), exactly as
 *    USB says, and reported in last_error. A device answers only at its address (PERADDR), only after a
 *    bus reset, only on its endpoints; anything else times out (hrTIMEOUT).
 * Fidelity limits: SNDFIFO is one buffer (the chip has two; a driver that loads one packet at a time sees
 * no difference); the INT pin is reported as a level (edge mode, PINCTL.INTLEVEL = 0, is not pulsed); no
 * suspend/resume, no low-speed device, no hub, no isochronous endpoints; transactions do not wait for room
 * in the 1 ms frame; GPIO registers are plain storage.
 *
 * The phone (the device side: descriptors, ep0 requests, AOA, bulk pipes, faults) shares the chip's state
 * and clock, so it lives in this file too: one job, the USB port of the board with a phone plugged in.
 * Normal mode: Samsung 04E8:6860 (MTP + ADB). AOA: GET_PROTOCOL (51) answers the "aoa" version, SEND_STRING
 * (52) records strings 0..5, START (53) drops the phone off the bus START_DETACH_US after the status stage
 * and brings it back START_ATTACH_US later as 18D1:2D01, interface 0 = bulk IN 0x81 / OUT 0x02, 64 bytes.
 * Bulk OUT fills the app's buffer (NAK when full: USB flow control); bulk IN serves the app's writes, each
 * a transfer (short packet or ZLP at its end), NAK while empty. The app-side buffers hold APP_BUF bytes.
 */
#include "max3421e.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Registers (number, not the command byte). */
enum {
    R_RCVFIFO = 1, R_SNDFIFO = 2, R_SUDFIFO = 4, R_RCVBC = 6, R_SNDBC = 7,
    R_USBIRQ = 13, R_USBIEN = 14, R_USBCTL = 15, R_CPUCTL = 16, R_PINCTL = 17, R_REVISION = 18,
    R_IOPINS1 = 20, R_IOPINS2 = 21, R_GPINIRQ = 22, R_GPINIEN = 23, R_GPINPOL = 24,
    R_HIRQ = 25, R_HIEN = 26, R_MODE = 27, R_PERADDR = 28, R_HCTL = 29, R_HXFR = 30, R_HRSL = 31,
};
#define USBIRQ_OSCOK 0x01
#define USBCTL_CHIPRES 0x20
#define CPUCTL_IE 0x01
#define PINCTL_FDUPSPI 0x10
#define PINCTL_INTLEVEL 0x08
#define HIRQ_BUSEVENT 0x01
#define HIRQ_RCVDAV 0x04
#define HIRQ_SNDBAV 0x08
#define HIRQ_CONDET 0x20
#define HIRQ_FRAME 0x40
#define HIRQ_HXFRDN 0x80
#define MODE_HOST 0x01
#define MODE_LOWSPEED 0x02
#define MODE_SOFKAENAB 0x08
#define HCTL_BUSRST 0x01
#define HCTL_FRMRST 0x02
#define HCTL_SAMPLEBUS 0x04
#define HCTL_RCVTOG0 0x10
#define HCTL_RCVTOG1 0x20
#define HCTL_SNDTOG0 0x40
#define HCTL_SNDTOG1 0x80
#define HRSL_RCVTOGRD 0x10
#define HRSL_SNDTOGRD 0x20
#define HRSL_KSTATUS 0x40
#define HRSL_JSTATUS 0x80
enum { HR_SUCCESS = 0, HR_BUSY = 1, HR_BADREQ = 2, HR_NAK = 4, HR_STALL = 5, HR_TOGERR = 6, HR_BADBC = 8,
       HR_TIMEOUT = 14 };
#define REVISION 0x13

/* Times in simulated microseconds. */
#define OSC_START_US 200u     /* crystal start-up after a reset until OSCOKIRQ */
#define BUSRST_US 50000u      /* the chip's bus reset lasts 50 ms */
#define XFER_US 8u            /* token, handshake and turnaround of one transaction at full speed */
#define FRAME_US 1000u        /* full-speed frame */
#define START_DETACH_US 3000u /* AOA START: the phone drops off the bus this long after the status stage */
#define START_ATTACH_US 60000u /* ... and comes back as an accessory this long after dropping off */

#define MAXPKT 64u
#define APP_BUF 4096u         /* each app-side pipe buffer (bytes) */
#define MAX_TRANSFERS 64u     /* app writes whose ends are remembered (for short packets and ZLPs) */
#define STRING_MAX 256u
#define CFG_MAX 1024u        /* the longest configuration descriptor a test may give the phone (past the host's 512) */
#define NONE_US UINT64_MAX

/* Token bits of HXFR: HS(7) ISO(6) OUTNIN(5) SETUP(4) EP(3:0). */
enum { TOK_IN = 0x00, TOK_SETUP = 0x10, TOK_OUT = 0x20, TOK_HSIN = 0x80, TOK_HSOUT = 0xA0 };

/* Device (phone) state, as USB chapter 9 names it. */
enum { DEV_DETACHED, DEV_POWERED, DEV_DEFAULT, DEV_ADDRESS, DEV_CONFIGURED };
/* Control pipe stage. */
enum { CTL_IDLE, CTL_DATA_IN, CTL_DATA_OUT, CTL_STATUS_IN, CTL_STALLED };
/* What a control write does once its status stage completes. */
enum { ACT_NONE, ACT_ADDRESS, ACT_CONFIG, ACT_STRING, ACT_START };

typedef struct {
    uint8_t buf[APP_BUF];
    uint32_t head, len;
} ring_t;

/* What the device sends back for an IN token. */
typedef struct {
    int result;        /* HR_* */
    int pid;           /* DATA0/1 the device sent (IN) */
    unsigned len;      /* bytes the device sent (IN) */
    uint8_t data[MAXPKT];
    int status;        /* ep0: this IN is the status stage of a control write */
} answer_t;

struct max3421e {
    uint64_t now;
    /* chip */
    uint8_t reg[32];
    int selected, in_command, cmd_reg, cmd_write;
    int res_low;
    uint64_t osc_ok_at, busrst_end_at, xfer_done_at, next_frame_at;
    uint8_t xfer_token;
    int in_data;         /* an IN's data packet is on the wire: xfer_done_at is its end */
    answer_t in_answer;  /* ... and this is it */
    uint8_t sud[8];
    unsigned sud_ptr;
    uint8_t snd[MAXPKT];
    unsigned snd_ptr, snd_count;
    int snd_loaded;
    uint8_t rcv[2][MAXPKT];
    unsigned rcv_len[2], rcv_ptr;
    int rcv_full[2], rcv_cur;
    int rcvtog, sndtog;
    uint8_t bus; /* HRSL J/K bits last sampled */
    char last_error[200];

    /* phone */
    int state, accessory, aoa_version;
    uint8_t address, new_address;
    int config;
    int ctl, action, ctl_toggle;
    uint8_t setup[8];
    uint8_t ctl_buf[CFG_MAX > STRING_MAX + 4 ? CFG_MAX : STRING_MAX + 4];
    unsigned ctl_len, ctl_pos;
    int in_toggle[16], out_toggle[16];
    unsigned nak_count, nak_left;
    unsigned lost_acks; /* fault: the handshakes of this many more bulk OUT packets the phone takes are lost */
    uint8_t last_out[MAXPKT]; /* the last bulk OUT packet the phone took: a repeat must be this packet */
    unsigned last_out_len;
    int stall_ep;
    int clear_halt_nak; /* fault: the status stage of every CLEAR_FEATURE(ENDPOINT_HALT) is NAKed, for ever */
    unsigned packet_size;
    int zlp, zlp_due;
    int dead_osc;     /* fault: the crystal does not start: OSCOKIRQ never rises */
    int never_switch; /* fault: START is acknowledged, the phone stays in its normal mode (1), or drops off
                         and comes back in its normal mode, a new device each time (2) */
    char strings[6][STRING_MAX + 1];
    /* The configuration descriptors this phone gives, its own copies, and their lengths (the bytes its
     * GET_DESCRIPTOR answers, whatever wTotalLength says): the "config_value" fault edits their
     * bConfigurationValue (byte 5), a value 0 making the one configuration impossible to select;
     * max3421e_descriptor() replaces them whole. */
    uint8_t cfg_normal[CFG_MAX], cfg_accessory[CFG_MAX];
    unsigned cfg_normal_len, cfg_accessory_len;
    /* Its device descriptors, its own copies, and their lengths: the "ep0_packet" fault edits their
     * bMaxPacketSize0 (byte 7), which is also the size of the data packets it sends on endpoint 0 (clamped
     * to the FIFO's 64); max3421e_descriptor() replaces them whole. */
    uint8_t dev_normal[MAXPKT], dev_accessory[MAXPKT];
    unsigned dev_normal_len, dev_accessory_len;
    /* fault: a chip that raises CONDETIRQ this long after each bus reset ends (0: never, the default); and
     * when the next such event is due */
    unsigned condet_after_reset_us;
    uint64_t condet_at;
    uint64_t detach_at, attach_at;
    ring_t to_board, to_app;     /* app -> bulk IN, bulk OUT -> app */
    uint64_t written, served;    /* bytes ever accepted for bulk IN / served on it */
    uint64_t ends[MAX_TRANSFERS]; /* 'written' at the end of each pending app write */
    unsigned n_ends, first_end;
};

static void error(max3421e_t *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void error(max3421e_t *m, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m->last_error, sizeof m->last_error, fmt, ap);
    va_end(ap);
}

/* ---------------------------------------------------------------- the phone's descriptors */

static const uint8_t DEV_NORMAL[18] = {18, 1, 0x00, 0x02, 0, 0, 0, MAXPKT, 0xE8, 0x04, 0x60, 0x68,
                                       0x00, 0x04, 1, 2, 3, 1}; /* Samsung 04E8:6860 (MTP + ADB) */
static const uint8_t DEV_ACCESSORY[18] = {18, 1, 0x00, 0x02, 0, 0, 0, MAXPKT, 0xD1, 0x18, 0x01, 0x2D,
                                          0x00, 0x04, 1, 2, 3, 1}; /* Google 18D1:2D01 (accessory + ADB) */
static const uint8_t CFG_NORMAL[62] = {
    9, 2, 62, 0, 2, 1, 0, 0x80, 250,
    9, 4, 0, 0, 3, 0x06, 0x01, 0x01, 4,   /* MTP (still image class) */
    7, 5, 0x81, 2, MAXPKT, 0, 0,
    7, 5, 0x01, 2, MAXPKT, 0, 0,
    7, 5, 0x82, 3, 28, 0, 6,
    9, 4, 1, 0, 2, 0xFF, 0x42, 0x01, 5,   /* ADB */
    7, 5, 0x83, 2, MAXPKT, 0, 0,
    7, 5, 0x02, 2, MAXPKT, 0, 0,
};
/* Accessory: interface 0 is the accessory's bulk pair (IN 0x81, OUT 0x02: not the same number, so a host
 * that reads the descriptor rather than guessing is the one that works), interface 1 ADB. */
static const uint8_t CFG_ACCESSORY[55] = {
    9, 2, 55, 0, 2, 1, 0, 0x80, 250,
    9, 4, 0, 0, 2, 0xFF, 0xFF, 0x00, 0,
    7, 5, 0x81, 2, MAXPKT, 0, 0,
    7, 5, 0x02, 2, MAXPKT, 0, 0,
    9, 4, 1, 0, 2, 0xFF, 0x42, 0x01, 5,
    7, 5, 0x83, 2, MAXPKT, 0, 0,
    7, 5, 0x03, 2, MAXPKT, 0, 0,
};
_Static_assert(sizeof CFG_NORMAL <= CFG_MAX && sizeof CFG_ACCESSORY <= CFG_MAX,
               "the phone's own copies of its configuration descriptors");
#define EP_ACC_IN 1
#define EP_ACC_OUT 2
static const char *const STRINGS[] = {NULL, "samsung", "SAMSUNG_Android", "R58M12ABCDE", "MTP", "ADB Interface"};

/* ---------------------------------------------------------------- app-side rings */

static uint32_t ring_put(ring_t *r, const uint8_t *p, uint32_t n)
{
    uint32_t k = 0;
    for (; k < n && r->len < APP_BUF; k++, r->len++)
        r->buf[(r->head + r->len) % APP_BUF] = p[k];
    return k;
}

static uint32_t ring_get(ring_t *r, uint8_t *p, uint32_t n)
{
    uint32_t k = 0;
    for (; k < n && r->len > 0; k++, r->len--, r->head = (r->head + 1) % APP_BUF)
        if (p)
            p[k] = r->buf[r->head];
    return k;
}

/* ---------------------------------------------------------------- phone state changes */

static void phone_reset_pipes(max3421e_t *m)
{
    memset(m->in_toggle, 0, sizeof m->in_toggle);
    memset(m->out_toggle, 0, sizeof m->out_toggle);
    m->ctl = CTL_IDLE;
    m->action = ACT_NONE;
    m->zlp_due = 0;
    m->last_out_len = MAXPKT + 1; /* no packet taken since: nothing is a repeat */
}

static void flush_to_board(max3421e_t *m)
{
    ring_get(&m->to_board, NULL, m->to_board.len);
    m->served = m->written;
    m->n_ends = m->first_end = 0;
}

static int host_mode(const max3421e_t *m) { return (m->reg[R_MODE] & MODE_HOST) != 0; }

static void phone_detach(max3421e_t *m)
{
    if (m->state == DEV_DETACHED)
        return;
    m->state = DEV_DETACHED;
    m->accessory = 0;
    m->address = 0;
    m->config = 0;
    phone_reset_pipes(m);
    flush_to_board(m); /* the app's writes fail once the accessory is gone */
    m->detach_at = m->attach_at = NONE_US;
    if (host_mode(m))
        m->reg[R_HIRQ] |= HIRQ_CONDET;
}

static void phone_attach(max3421e_t *m, int accessory)
{
    if (m->state != DEV_DETACHED)
        return;
    m->state = DEV_POWERED; /* answers nothing until a bus reset */
    m->accessory = accessory;
    m->address = 0;
    m->config = 0;
    phone_reset_pipes(m);
    if (host_mode(m))
        m->reg[R_HIRQ] |= HIRQ_CONDET;
}

/* ---------------------------------------------------------------- control requests */

static unsigned string_descriptor(uint8_t *out, const char *s)
{
    unsigned n = 0;
    out[n++] = 0;
    out[n++] = 3;
    for (; *s && n + 2 <= 2 * 63 + 2; s++) {
        out[n++] = (uint8_t)*s; /* the strings are ASCII: UTF-16LE is the byte and a zero */
        out[n++] = 0;
    }
    out[0] = (uint8_t)n;
    return n;
}

/* The bConfigurationValue of the configuration this phone gives in its present mode. */
static unsigned configuration_value(const max3421e_t *m)
{
    return (m->accessory ? m->cfg_accessory : m->cfg_normal)[5];
}

/* A SETUP arrived (always accepted: a device cannot NAK a SETUP). Decides the data stage or a STALL. */
static void control_setup(max3421e_t *m)
{
    const uint8_t *s = m->setup;
    uint8_t type = s[0], req = s[1];
    unsigned value = s[2] | (unsigned)s[3] << 8, index = s[4] | (unsigned)s[5] << 8,
             length = s[6] | (unsigned)s[7] << 8;
    const uint8_t *src = NULL;
    unsigned n = 0;
    m->action = ACT_NONE;
    m->ctl_pos = 0;
    m->ctl_toggle = 1; /* the data and status stages start with DATA1 */
    m->zlp_due = 0;
    int ok = 1;
    if (type == 0x80 && req == 6) { /* GET_DESCRIPTOR */
        unsigned dtype = value >> 8, didx = value & 0xFF;
        if (dtype == 1) {
            src = m->accessory ? m->dev_accessory : m->dev_normal;
            n = m->accessory ? m->dev_accessory_len : m->dev_normal_len;
        } else if (dtype == 2 && didx == 0) {
            src = m->accessory ? m->cfg_accessory : m->cfg_normal;
            n = m->accessory ? m->cfg_accessory_len : m->cfg_normal_len;
        } else if (dtype == 3 && didx == 0) {
            static const uint8_t LANG[4] = {4, 3, 0x09, 0x04};
            src = LANG;
            n = 4;
        } else if (dtype == 3 && didx < sizeof STRINGS / sizeof *STRINGS) {
            n = string_descriptor(m->ctl_buf, STRINGS[didx]);
        } else {
            ok = 0; /* device qualifier etc.: a full-speed-only device STALLs them */
        }
    } else if (type == 0x80 && req == 0) { /* GET_STATUS (device) */
        m->ctl_buf[0] = m->ctl_buf[1] = 0;
        n = 2;
    } else if (type == 0x80 && req == 8) { /* GET_CONFIGURATION */
        m->ctl_buf[0] = (uint8_t)m->config;
        n = 1;
    } else if (type == 0x00 && req == 5 && length == 0 && value <= 127) { /* SET_ADDRESS */
        m->new_address = (uint8_t)value;
        m->action = ACT_ADDRESS;
    } else if (type == 0x00 && req == 9 && length == 0 && (value == 0 || value == configuration_value(m)) &&
               m->state >= DEV_ADDRESS) { /* 0: back to the address state (USB 2.0 9.4.7) */
        m->new_address = (uint8_t)value; /* SET_CONFIGURATION: the value rides in new_address */
        m->action = ACT_CONFIG;
    } else if (type == 0x01 && req == 11 && length == 0 && value == 0 && index <= 1 && m->config) {
        /* SET_INTERFACE alternate 0: nothing to change */
    } else if (type == 0x02 && req == 1 && length == 0 && value == 0 && m->config) {
        /* CLEAR_FEATURE(ENDPOINT_HALT): the endpoint's toggle restarts at DATA0 */
        unsigned ep = index & 0x0F;
        if (index & 0x80) {
            m->in_toggle[ep] = 0;
        } else {
            m->out_toggle[ep] = 0;
            m->last_out_len = MAXPKT + 1;
        }
    } else if (type == 0xC0 && req == 51) { /* AOA GET_PROTOCOL */
        m->ctl_buf[0] = (uint8_t)m->aoa_version;
        m->ctl_buf[1] = 0;
        n = 2;
    } else if (type == 0x40 && req == 52 && m->aoa_version > 0) { /* AOA SEND_STRING */
        if (index > 5 || length == 0 || length > STRING_MAX) {
            error(m, "SEND_STRING index %u length %u (index 0..5, length 1..%u)", index, length, STRING_MAX);
            ok = 0;
        } else {
            m->action = ACT_STRING;
        }
    } else if (type == 0x40 && req == 53 && length == 0 && m->aoa_version > 0) { /* AOA START */
        m->action = ACT_START;
    } else {
        ok = 0;
    }
    if (!ok) {
        m->ctl = CTL_STALLED;
        return;
    }
    if (type & 0x80) {
        if (src)
            memcpy(m->ctl_buf, src, n);
        m->ctl_len = n < length ? n : length;
        m->ctl = CTL_DATA_IN;
    } else {
        m->ctl_len = length;
        m->ctl = length ? CTL_DATA_OUT : CTL_STATUS_IN;
    }
}

/* The status stage of a control write completed: the request takes effect now (USB 2.0 9.4.6: the
 * address changes after the status stage). */
static void control_done(max3421e_t *m)
{
    switch (m->action) {
    case ACT_ADDRESS:
        m->address = m->new_address;
        m->state = m->address ? DEV_ADDRESS : DEV_DEFAULT;
        break;
    case ACT_CONFIG:
        m->config = m->new_address;
        m->state = m->config ? DEV_CONFIGURED : DEV_ADDRESS;
        memset(m->in_toggle + 1, 0, sizeof m->in_toggle - sizeof *m->in_toggle);
        memset(m->out_toggle + 1, 0, sizeof m->out_toggle - sizeof *m->out_toggle);
        break;
    case ACT_STRING: {
        unsigned idx = m->setup[4], n = 0;
        while (n < m->ctl_len && m->ctl_buf[n])
            n++;
        if (n == m->ctl_len)
            error(m, "SEND_STRING %u: %u bytes without the terminating zero", idx, m->ctl_len);
        memcpy(m->strings[idx], m->ctl_buf, n);
        m->strings[idx][n] = 0;
        break;
    }
    case ACT_START:
        if (m->never_switch != 1) /* a phone without the accessory app, or AOA barred by policy: no switch */
            m->detach_at = m->now + START_DETACH_US;
        break;
    default:
        break;
    }
    m->action = ACT_NONE;
    m->ctl = CTL_IDLE;
}

/* ---------------------------------------------------------------- one transaction, device side */

static int nak_fault(max3421e_t *m)
{
    if (m->nak_left > 0) {
        m->nak_left--;
        return 1;
    }
    m->nak_left = m->nak_count;
    return 0;
}

static int stall_fault(max3421e_t *m, unsigned ep)
{
    if (m->stall_ep >= 0 && (unsigned)m->stall_ep == ep) {
        m->stall_ep = -1;
        if (ep == 0)
            m->ctl = CTL_STALLED;
        return 1;
    }
    return 0;
}

/* ep0 IN: a data packet of a control read, or the zero-length status of a control write. */
static answer_t ep0_in(max3421e_t *m, int handshake)
{
    answer_t a = {HR_SUCCESS, 1, 0, {0}, 0};
    if (m->ctl == CTL_STALLED || stall_fault(m, 0)) {
        a.result = HR_STALL;
    } else if (m->ctl == CTL_DATA_IN && !handshake) {
        if (nak_fault(m)) {
            a.result = HR_NAK;
            return a;
        }
        unsigned n = m->ctl_len - m->ctl_pos, mps = (m->accessory ? m->dev_accessory : m->dev_normal)[7];
        if (mps < 1 || mps > MAXPKT)
            mps = MAXPKT; /* a size no full-speed FIFO holds: what the wire can carry */
        a.len = n > mps ? mps : n; /* 0 once all is sent: a ZLP ends a transfer of whole packets */
        memcpy(a.data, m->ctl_buf + m->ctl_pos, a.len);
        a.pid = m->ctl_toggle;
    } else if (m->ctl == CTL_STATUS_IN && m->clear_halt_nak && m->setup[0] == 0x02 && m->setup[1] == 1) {
        a.result = HR_NAK; /* a phone that never finishes clearing its endpoint's halt */
    } else if (m->ctl == CTL_STATUS_IN || (m->ctl == CTL_DATA_OUT && m->ctl_pos == m->ctl_len)) {
        a.pid = 1;
        a.status = 1;
    } else {
        error(m, "IN on endpoint 0 in control stage %d (%s)", m->ctl, handshake ? "HS-IN" : "IN");
        m->ctl = CTL_STALLED;
        a.result = HR_STALL;
    }
    return a;
}

/* The host acknowledged an IN packet on ep0 (the device now moves on). */
static void ep0_in_acked(max3421e_t *m, const answer_t *a)
{
    if (a->status) {
        control_done(m); /* status stage of a control write */
    } else {
        m->ctl_pos += a->len;
        m->ctl_toggle ^= 1;
    }
}

static answer_t ep0_out(max3421e_t *m, const uint8_t *p, unsigned n, int pid, int handshake)
{
    answer_t a = {HR_SUCCESS, pid, 0, {0}, 0};
    if (m->ctl == CTL_STALLED || stall_fault(m, 0)) {
        a.result = HR_STALL;
    } else if (m->ctl == CTL_DATA_OUT && !handshake) {
        if (nak_fault(m)) {
            a.result = HR_NAK;
        } else if (pid != m->ctl_toggle) {
            error(m, "OUT on endpoint 0 with DATA%d, the device expected DATA%d (discarded as a repeat)", pid,
                  m->ctl_toggle);
        } else if (m->ctl_pos + n > m->ctl_len) {
            error(m, "control OUT data of %u bytes past wLength %u", m->ctl_pos + n, m->ctl_len);
            m->ctl = CTL_STALLED;
            a.result = HR_STALL;
        } else {
            memcpy(m->ctl_buf + m->ctl_pos, p, n);
            m->ctl_pos += n;
            m->ctl_toggle ^= 1;
        }
    } else if (m->ctl == CTL_DATA_IN && n == 0) {
        /* status stage of a control read (HS-OUT, or a zero-length OUT DATA1) */
        if (pid != 1)
            error(m, "control read status stage with DATA0");
        m->ctl = CTL_IDLE;
    } else {
        error(m, "OUT on endpoint 0 in control stage %d (%s, %u bytes)", m->ctl, handshake ? "HS-OUT" : "OUT", n);
        m->ctl = CTL_STALLED;
        a.result = HR_STALL;
    }
    return a;
}

/* Bulk IN of the accessory: the app's queued bytes, in packets no longer than the "packet" fault and never
 * past the end of one app write (each write is one transfer, ended by a short packet or a ZLP). */
static answer_t bulk_in(max3421e_t *m)
{
    answer_t a = {HR_SUCCESS, m->in_toggle[EP_ACC_IN], 0, {0}, 0};
    if (stall_fault(m, EP_ACC_IN)) {
        a.result = HR_STALL;
        return a;
    }
    if (m->zlp_due)
        return a;
    if (m->to_board.len == 0 || nak_fault(m)) {
        a.result = HR_NAK;
        return a;
    }
    uint64_t end = m->n_ends ? m->ends[m->first_end] : m->written;
    uint64_t n = end - m->served;
    if (n > m->packet_size)
        n = m->packet_size;
    a.len = (unsigned)n;
    for (unsigned k = 0; k < a.len; k++)
        a.data[k] = m->to_board.buf[(m->to_board.head + k) % APP_BUF];
    return a;
}

static void bulk_in_acked(max3421e_t *m, const answer_t *a)
{
    m->in_toggle[EP_ACC_IN] ^= 1;
    if (m->zlp_due) {
        m->zlp_due = 0;
        return;
    }
    ring_get(&m->to_board, NULL, a->len);
    m->served += a->len;
    if (m->n_ends && m->served == m->ends[m->first_end]) {
        m->first_end = (m->first_end + 1) % MAX_TRANSFERS;
        m->n_ends--;
        if (m->zlp && a->len == MAXPKT)
            m->zlp_due = 1;
    }
}

static answer_t bulk_out(max3421e_t *m, const uint8_t *p, unsigned n, int pid)
{
    answer_t a = {HR_SUCCESS, pid, 0, {0}, 0};
    if (stall_fault(m, EP_ACC_OUT)) {
        a.result = HR_STALL;
    } else if (nak_fault(m) || APP_BUF - m->to_app.len < n) {
        a.result = HR_NAK; /* the app has not read: no room, the phone NAKs (USB flow control, nothing lost) */
    } else if (pid != m->out_toggle[EP_ACC_OUT]) {
        /* A repeat to the device: acknowledged and discarded, as USB says. Right after a lost handshake it is
         * the host sending the very packet again; anything else is bytes the app never gets. */
        if (n != m->last_out_len || memcmp(p, m->last_out, n))
            error(m, "bulk OUT on endpoint %d with DATA%d, the device expected DATA%d (discarded as a repeat: "
                     "%u bytes lost, not the %u-byte packet it took last)",
                  EP_ACC_OUT, pid, m->out_toggle[EP_ACC_OUT], n, m->last_out_len);
    } else {
        ring_put(&m->to_app, p, n);
        m->out_toggle[EP_ACC_OUT] ^= 1;
        memcpy(m->last_out, p, n);
        m->last_out_len = n;
        if (m->lost_acks) { /* taken, but its ACK never reaches the chip: no handshake, a bus timeout */
            m->lost_acks--;
            a.result = HR_TIMEOUT;
        }
    }
    return a;
}

/* ---------------------------------------------------------------- chip: transactions */

static void set_result(max3421e_t *m, int result)
{
    m->reg[R_HRSL] = (uint8_t)((m->reg[R_HRSL] & 0xC0) | (m->rcvtog ? HRSL_RCVTOGRD : 0) |
                               (m->sndtog ? HRSL_SNDTOGRD : 0) | (result & 0x0F));
    m->reg[R_HIRQ] |= HIRQ_HXFRDN;
}

static void show_rcv(max3421e_t *m)
{
    if (m->rcv_full[m->rcv_cur]) {
        m->reg[R_RCVBC] = (uint8_t)m->rcv_len[m->rcv_cur];
        m->reg[R_HIRQ] |= HIRQ_RCVDAV;
    } else {
        m->reg[R_HIRQ] &= (uint8_t)~HIRQ_RCVDAV;
    }
    m->rcv_ptr = 0;
}

/* Does the phone answer a token at PERADDR on this endpoint? Otherwise the chip times out. */
static int addressed(max3421e_t *m, unsigned ep, int in)
{
    if (m->state == DEV_DETACHED)
        return 0;
    if (m->busrst_end_at != NONE_US) {
        error(m, "transaction during bus reset");
        return 0;
    }
    if (m->reg[R_MODE] & MODE_LOWSPEED) {
        error(m, "MODE.LOWSPEED set but the phone is full speed");
        return 0;
    }
    if (m->state == DEV_POWERED) {
        error(m, "transaction before a bus reset (the device is not in its default state)");
        return 0;
    }
    if (m->reg[R_PERADDR] != m->address) {
        error(m, "PERADDR %u: the phone answers at address %u", m->reg[R_PERADDR], m->address);
        return 0;
    }
    if (ep == 0)
        return 1;
    if (m->state != DEV_CONFIGURED) {
        error(m, "endpoint %u addressed before SET_CONFIGURATION", ep);
        return 0;
    }
    const uint8_t *cfg = m->accessory ? m->cfg_accessory : m->cfg_normal;
    unsigned len = m->accessory ? m->cfg_accessory_len : m->cfg_normal_len;
    /* the endpoints its descriptor says, as far as it parses (a test may give it a malformed one), of the
     * interfaces' alternate settings 0 only: the phone takes SET_INTERFACE to no other, so no other's
     * endpoints are ever active (USB 2.0 9.6.5) */
    unsigned alternate = 0;
    for (unsigned k = 0; k + 3 < len && cfg[k] >= 2; k += cfg[k]) {
        if (cfg[k + 1] == 4)
            alternate = cfg[k + 3];
        else if (cfg[k + 1] == 5 && !alternate && (cfg[k + 2] & 0x0F) == ep && ((cfg[k + 2] & 0x80) != 0) == in)
            return 1;
    }
    error(m, "no %s endpoint %u in this configuration", in ? "IN" : "OUT", ep);
    return 0;
}

static void finish_in(max3421e_t *m, unsigned ep, int handshake, const answer_t *ap);

static void complete_in(max3421e_t *m, unsigned ep, int handshake)
{
    answer_t a;
    if (ep == 0)
        a = ep0_in(m, handshake);
    else if (m->accessory && ep == EP_ACC_IN)
        a = bulk_in(m);
    else
        a = (answer_t){HR_NAK, 0, 0, {0}, 0}; /* MTP, ADB: nothing to say */
    if (a.result != HR_SUCCESS) {
        set_result(m, a.result);
        return;
    }
    if (a.len > 0) { /* the data packet takes its wire time; the host acknowledges it at its end */
        m->in_answer = a;
        m->in_data = 1;
        m->xfer_done_at = m->now + a.len * 2 / 3 + 1;
        return;
    }
    finish_in(m, ep, handshake, &a);
}

/* The end of an IN's data packet: the host acknowledges it and the chip checks and stores it. */
static void finish_in(max3421e_t *m, unsigned ep, int handshake, const answer_t *ap)
{
    answer_t a = *ap;
    m->in_data = 0;
    if (m->state == DEV_DETACHED) { /* unplugged mid-packet: the chip sees no valid packet end */
        set_result(m, HR_TIMEOUT);
        return;
    }
    int expected = handshake ? 1 : m->rcvtog;
    /* The host acknowledges whatever it received, so the device moves on either way. */
    if (ep == 0)
        ep0_in_acked(m, &a);
    else
        bulk_in_acked(m, &a);
    if (a.pid != expected) {
        error(m, "IN on endpoint %u: DATA%d received, RCVTOG expected DATA%d (hrTOGERR)", ep, a.pid, expected);
        set_result(m, HR_TOGERR);
        return;
    }
    if (!handshake) {
        int slot = !m->rcv_full[m->rcv_cur] ? m->rcv_cur : 1 - m->rcv_cur;
        memcpy(m->rcv[slot], a.data, a.len);
        m->rcv_len[slot] = a.len;
        m->rcv_full[slot] = 1;
        m->rcvtog ^= 1;
        if (slot == m->rcv_cur)
            show_rcv(m);
    }
    set_result(m, HR_SUCCESS);
}

static void complete_out(max3421e_t *m, unsigned ep, int handshake)
{
    answer_t a;
    unsigned n = handshake ? 0 : m->snd_count;
    int pid = handshake ? 1 : m->sndtog;
    if (ep == 0)
        a = ep0_out(m, m->snd, n, pid, handshake);
    else if (m->accessory && ep == EP_ACC_OUT)
        a = bulk_out(m, m->snd, n, pid);
    else
        a = (answer_t){HR_NAK, pid, 0, {0}, 0};
    if (a.result == HR_SUCCESS && !handshake) {
        m->sndtog ^= 1;
        m->snd_loaded = 0;
        m->reg[R_HIRQ] |= HIRQ_SNDBAV;
    }
    set_result(m, a.result);
}

static void complete_transfer(max3421e_t *m)
{
    uint8_t tok = m->xfer_token & 0xF0;
    unsigned ep = m->xfer_token & 0x0F;
    m->xfer_done_at = NONE_US;
    if (m->in_data) {
        finish_in(m, ep, tok == TOK_HSIN, &m->in_answer);
        return;
    }
    if (!addressed(m, ep, tok == TOK_IN || tok == TOK_HSIN)) {
        set_result(m, HR_TIMEOUT);
        return;
    }
    switch (tok) {
    case TOK_SETUP:
        if (ep != 0) {
            set_result(m, HR_TIMEOUT);
            return;
        }
        memcpy(m->setup, m->sud, 8);
        control_setup(m);
        set_result(m, HR_SUCCESS);
        break;
    case TOK_IN:
    case TOK_HSIN:
        complete_in(m, ep, tok == TOK_HSIN);
        break;
    case TOK_OUT:
    case TOK_HSOUT:
        complete_out(m, ep, tok == TOK_HSOUT);
        break;
    default:
        set_result(m, HR_TIMEOUT);
        break;
    }
}

static void launch(max3421e_t *m, uint8_t token)
{
    uint8_t tok = token & 0xF0;
    if (m->xfer_done_at != NONE_US) {
        error(m, "HXFR 0x%02X written while a transfer is in progress", token);
        return;
    }
    if (!host_mode(m)) {
        error(m, "HXFR 0x%02X written without MODE.HOST", token);
        return;
    }
    if (tok != TOK_SETUP && tok != TOK_IN && tok != TOK_OUT && tok != TOK_HSIN && tok != TOK_HSOUT) {
        error(m, "HXFR token 0x%02X is not SETUP, IN, OUT, HS-IN or HS-OUT", token);
        set_result(m, HR_BADREQ);
        return;
    }
    m->reg[R_HIRQ] &= (uint8_t)~HIRQ_HXFRDN;
    unsigned bytes = 0;
    if (tok == TOK_SETUP) {
        if (m->sud_ptr != 8 && m->sud_ptr != 0)
            error(m, "SETUP with %u bytes written to SUDFIFO", m->sud_ptr);
        /* Every SETUP sends SUDFIFO's 8 bytes from its start, and the CPU's next write starts there too,
         * whatever became of this one: a driver may launch the SETUP again as it is (USB Host Shield 2.0
         * retries HXFR alone) or write the 8 bytes again first (Linux's max3421-hcd does, at every
         * retransmission); both work on the chip. The pointer restarted only at a SETUP the phone took, so
         * a rewrite after one that timed out (the phone unplugged, or not yet reset) was "past 8 bytes". */
        m->sud_ptr = 0;
        bytes = 8;
    } else if (tok == TOK_OUT) {
        if (!m->snd_loaded)
            error(m, "OUT launched with no SNDBC written since the last acknowledged OUT");
        if (m->snd_count > MAXPKT) {
            error(m, "SNDBC %u is more than 64", m->snd_count);
            set_result(m, HR_BADBC);
            return;
        }
        bytes = m->snd_count;
    } else if (tok == TOK_IN) {
        if (m->rcv_full[0] && m->rcv_full[1]) {
            error(m, "IN launched with both RCVFIFO buffers full (RCVDAVIRQ not cleared)");
            set_result(m, HR_BUSY);
            return;
        }
    }
    m->xfer_token = token;
    /* 12 Mb/s: 2/3 us a byte. An IN's data, if the device sends any, adds its own time (complete_in). */
    m->xfer_done_at = m->now + XFER_US + bytes * 2 / 3;
}

/* ---------------------------------------------------------------- chip: registers */

static void chip_reset(max3421e_t *m, int keep_spi)
{
    uint8_t pinctl = m->reg[R_PINCTL], usbctl = m->reg[R_USBCTL];
    memset(m->reg, 0, sizeof m->reg);
    if (keep_spi) {
        m->reg[R_PINCTL] = pinctl;
        m->reg[R_USBCTL] = usbctl;
    }
    m->reg[R_REVISION] = REVISION;
    m->reg[R_HIRQ] = HIRQ_SNDBAV;
    m->sud_ptr = m->snd_ptr = m->snd_count = 0;
    m->snd_loaded = 0;
    m->rcv_full[0] = m->rcv_full[1] = 0;
    m->rcv_cur = 0;
    m->rcv_ptr = 0;
    m->rcvtog = m->sndtog = 0;
    m->bus = 0;
    m->busrst_end_at = m->xfer_done_at = m->next_frame_at = m->condet_at = NONE_US;
    m->in_data = 0;
    m->osc_ok_at = m->now + OSC_START_US;
    /* Without the chip's SOFs the phone suspends; it needs a bus reset before it answers again. */
    if (m->state != DEV_DETACHED) {
        m->state = DEV_POWERED;
        m->address = 0;
        m->config = 0;
        phone_reset_pipes(m);
    }
}

static int attached_fs(const max3421e_t *m) { return m->state != DEV_DETACHED; }

static void update_frames(max3421e_t *m)
{
    /* The frame timer runs whether or not a device listens; SOFs pause during a bus reset. */
    int running = host_mode(m) && (m->reg[R_MODE] & MODE_SOFKAENAB) && m->busrst_end_at == NONE_US;
    if (!running)
        m->next_frame_at = NONE_US;
    else if (m->next_frame_at == NONE_US)
        m->next_frame_at = m->now + FRAME_US;
}

static void write_reg(max3421e_t *m, int r, uint8_t v)
{
    switch (r) {
    case R_SUDFIFO:
        if (m->sud_ptr >= 8) {
            error(m, "SUDFIFO written past 8 bytes");
            return;
        }
        m->sud[m->sud_ptr++] = v;
        break;
    case R_SNDFIFO:
        if (m->snd_ptr >= MAXPKT) {
            error(m, "SNDFIFO written past 64 bytes");
            return;
        }
        m->snd[m->snd_ptr++] = v;
        break;
    case R_SNDBC:
        m->snd_count = v;
        m->snd_ptr = 0;
        m->snd_loaded = 1;
        m->reg[R_SNDBC] = v;
        m->reg[R_HIRQ] &= (uint8_t)~HIRQ_SNDBAV;
        break;
    case R_RCVFIFO:
    case R_RCVBC:
    case R_REVISION:
    case R_HRSL:
        error(m, "write to read-only register %d", r);
        break;
    case R_USBIRQ:
        m->reg[R_USBIRQ] &= (uint8_t)~v;
        break;
    case R_GPINIRQ:
        m->reg[R_GPINIRQ] &= (uint8_t)~v;
        break;
    case R_HIRQ:
        if (v & HIRQ_RCVDAV && m->rcv_full[m->rcv_cur]) {
            m->rcv_full[m->rcv_cur] = 0;
            m->rcv_cur ^= 1;
            show_rcv(m);
        }
        /* SNDBAVIRQ is read-only (SNDBC clears it); RCVDAVIRQ follows the buffers. */
        m->reg[R_HIRQ] &= (uint8_t)~(v & (uint8_t)~(HIRQ_SNDBAV | HIRQ_RCVDAV));
        break;
    case R_USBCTL:
        m->reg[R_USBCTL] = v;
        if (v & USBCTL_CHIPRES) {
            chip_reset(m, 1);
            m->reg[R_USBCTL] = v;
            m->osc_ok_at = NONE_US; /* the oscillator stays off while CHIPRES is held */
        } else if (m->osc_ok_at == NONE_US && !(m->reg[R_USBIRQ] & USBIRQ_OSCOK)) {
            m->osc_ok_at = m->now + OSC_START_US;
        }
        break;
    case R_MODE: {
        int was_host = host_mode(m);
        m->reg[R_MODE] = v;
        if (!was_host && host_mode(m) && attached_fs(m))
            m->reg[R_HIRQ] |= HIRQ_CONDET;
        update_frames(m);
        break;
    }
    case R_HCTL:
        if (v & HCTL_RCVTOG0)
            m->rcvtog = 0;
        if (v & HCTL_RCVTOG1)
            m->rcvtog = 1;
        if (v & HCTL_SNDTOG0)
            m->sndtog = 0;
        if (v & HCTL_SNDTOG1)
            m->sndtog = 1;
        m->reg[R_HRSL] = (uint8_t)((m->reg[R_HRSL] & ~(HRSL_RCVTOGRD | HRSL_SNDTOGRD)) |
                                   (m->rcvtog ? HRSL_RCVTOGRD : 0) | (m->sndtog ? HRSL_SNDTOGRD : 0));
        m->reg[R_HCTL] = v & (HCTL_SAMPLEBUS | HCTL_BUSRST);
        if (v & HCTL_SAMPLEBUS) {
            /* full speed idle is J (D+ high); SE0 while detached or during a bus reset */
            m->bus = attached_fs(m) && m->busrst_end_at == NONE_US ? HRSL_JSTATUS : 0;
            m->reg[R_HRSL] = (uint8_t)((m->reg[R_HRSL] & 0x3F) | m->bus);
        }
        if (v & HCTL_FRMRST && m->next_frame_at != NONE_US)
            m->next_frame_at = m->now + FRAME_US;
        if (v & HCTL_BUSRST && m->busrst_end_at == NONE_US) {
            m->busrst_end_at = m->now + BUSRST_US;
            update_frames(m);
        }
        break;
    case R_HXFR:
        m->reg[R_HXFR] = v;
        launch(m, v);
        break;
    default:
        m->reg[r] = v;
        break;
    }
}

static uint8_t read_reg(max3421e_t *m, int r)
{
    if (r == R_RCVFIFO) {
        if (!m->rcv_full[m->rcv_cur] || m->rcv_ptr >= m->rcv_len[m->rcv_cur]) {
            error(m, "RCVFIFO read past RCVBC");
            return 0;
        }
        return m->rcv[m->rcv_cur][m->rcv_ptr++];
    }
    if (r == R_SNDFIFO || r == R_SUDFIFO)
        return 0;
    return m->reg[r];
}

/* ---------------------------------------------------------------- the API */

max3421e_t *max3421e_new(void)
{
    max3421e_t *m = calloc(1, sizeof *m);
    if (!m)
        return NULL;
    m->state = DEV_DETACHED;
    m->aoa_version = 2;
    m->stall_ep = -1;
    m->packet_size = MAXPKT;
    m->detach_at = m->attach_at = NONE_US;
    max3421e_descriptor(m, 1, 1, DEV_NORMAL, sizeof DEV_NORMAL);
    max3421e_descriptor(m, 2, 1, DEV_ACCESSORY, sizeof DEV_ACCESSORY);
    max3421e_descriptor(m, 1, 2, CFG_NORMAL, sizeof CFG_NORMAL);
    max3421e_descriptor(m, 2, 2, CFG_ACCESSORY, sizeof CFG_ACCESSORY);
    chip_reset(m, 0);
    phone_attach(m, 0);
    return m;
}

void max3421e_free(max3421e_t *m) { free(m); }

void max3421e_select(max3421e_t *m, int selected)
{
    /* Only an edge of SS counts: simavr re-raises a port's pins on every write to it, and a write to PORTB
     * in the middle of a command (SS staying low) must not start a new one. */
    selected = selected && !m->res_low;
    if (selected == m->selected)
        return;
    m->selected = selected;
    m->in_command = 0;
}

uint8_t max3421e_spi(max3421e_t *m, uint8_t mosi)
{
    if (!m->selected) {
        error(m, "SPI byte 0x%02X clocked with SS high%s", mosi, m->res_low ? " (chip held in reset)" : "");
        return 0xFF;
    }
    int fdup = (m->reg[R_PINCTL] & PINCTL_FDUPSPI) != 0;
    if (!m->in_command) {
        m->in_command = 1;
        m->cmd_reg = mosi >> 3;
        m->cmd_write = (mosi & 0x02) != 0;
        return fdup ? m->reg[R_HIRQ] : 0xFF;
    }
    if (m->cmd_write) {
        write_reg(m, m->cmd_reg, mosi);
        return fdup ? 0x00 : 0xFF;
    }
    if (!fdup) {
        error(m, "register %d read in half-duplex SPI mode (MISO unused until PINCTL.FDUPSPI)", m->cmd_reg);
        return 0xFF;
    }
    return read_reg(m, m->cmd_reg);
}

int max3421e_int_asserted(const max3421e_t *m)
{
    if (m->res_low || !(m->reg[R_CPUCTL] & CPUCTL_IE))
        return 0;
    return (m->reg[R_HIRQ] & m->reg[R_HIEN]) || (m->reg[R_USBIRQ] & m->reg[R_USBIEN]) ||
           (m->reg[R_GPINIRQ] & m->reg[R_GPINIEN]);
}

void max3421e_reset_pin(max3421e_t *m, int low)
{
    if (low && !m->res_low) {
        m->res_low = 1;
        m->selected = 0;
        chip_reset(m, 0);
        m->osc_ok_at = NONE_US;
    } else if (!low && m->res_low) {
        m->res_low = 0;
        m->osc_ok_at = m->now + OSC_START_US;
    }
}

static uint64_t earliest(const max3421e_t *m)
{
    uint64_t t = m->osc_ok_at;
    const uint64_t c[] = {m->busrst_end_at, m->xfer_done_at, m->next_frame_at, m->detach_at, m->attach_at,
                          m->condet_at};
    for (unsigned k = 0; k < sizeof c / sizeof *c; k++)
        if (c[k] < t)
            t = c[k];
    return t;
}

void max3421e_advance(max3421e_t *m, uint64_t now_us)
{
    if (now_us < m->now)
        return;
    if (m->next_frame_at != NONE_US && now_us > m->next_frame_at + 10 * FRAME_US)
        m->next_frame_at = now_us - (now_us - m->next_frame_at) % FRAME_US; /* a long jump: one FRAMEIRQ */
    for (uint64_t t; (t = earliest(m)) <= now_us;) {
        m->now = t;
        if (t == m->osc_ok_at) {
            m->osc_ok_at = NONE_US;
            if (!m->res_low && !m->dead_osc)
                m->reg[R_USBIRQ] |= USBIRQ_OSCOK;
        } else if (t == m->busrst_end_at) {
            m->busrst_end_at = NONE_US;
            m->reg[R_HCTL] &= (uint8_t)~HCTL_BUSRST;
            m->reg[R_HIRQ] |= HIRQ_BUSEVENT;
            if (m->condet_after_reset_us && host_mode(m))
                m->condet_at = t + m->condet_after_reset_us;
            if (m->state != DEV_DETACHED) {
                m->state = DEV_DEFAULT;
                m->address = 0;
                m->config = 0;
                phone_reset_pipes(m);
            }
            update_frames(m);
        } else if (t == m->xfer_done_at) {
            complete_transfer(m);
        } else if (t == m->next_frame_at) {
            m->reg[R_HIRQ] |= HIRQ_FRAME;
            m->next_frame_at += FRAME_US;
        } else if (t == m->detach_at) {
            phone_detach(m);
            m->attach_at = t + START_ATTACH_US;
            update_frames(m);
        } else if (t == m->condet_at) {
            m->condet_at = NONE_US;
            m->reg[R_HIRQ] |= HIRQ_CONDET;
        } else if (t == m->attach_at) {
            m->attach_at = NONE_US;
            phone_attach(m, m->never_switch != 2); /* never_switch 2: back in its normal mode */
            update_frames(m);
        }
    }
    m->now = now_us;
}

size_t max3421e_phone_read(max3421e_t *m, uint8_t *buf, size_t cap)
{
    return ring_get(&m->to_app, buf, cap > APP_BUF ? APP_BUF : (uint32_t)cap);
}

size_t max3421e_phone_write(max3421e_t *m, const uint8_t *buf, size_t len)
{
    if (!m->accessory || m->state != DEV_CONFIGURED || len == 0)
        return 0; /* no accessory open: the app's write fails */
    uint32_t n = ring_put(&m->to_board, buf, len > APP_BUF ? APP_BUF : (uint32_t)len);
    if (n == 0)
        return 0;
    m->written += n;
    if (m->n_ends < MAX_TRANSFERS) {
        m->ends[(m->first_end + m->n_ends) % MAX_TRANSFERS] = m->written;
        m->n_ends++;
    } else {
        m->ends[(m->first_end + m->n_ends - 1) % MAX_TRANSFERS] = m->written; /* merged into the last */
    }
    return n;
}

int max3421e_phone_mode(const max3421e_t *m)
{
    if (m->state == DEV_DETACHED)
        return 0;
    return m->accessory ? 2 : 1;
}

const char *max3421e_phone_string(const max3421e_t *m, int index)
{
    return index >= 0 && index < 6 ? m->strings[index] : "";
}

int max3421e_fault(max3421e_t *m, const char *name, double value)
{
    if (!strcmp(name, "nak") && value >= 0 && value <= 1e6) {
        m->nak_count = m->nak_left = (unsigned)value;
    } else if (!strcmp(name, "stall") && value >= 0 && value <= 15 && value == (int)value) {
        m->stall_ep = (int)value;
    } else if (!strcmp(name, "detach")) {
        phone_detach(m);
        /* the cable out: nor does a phone between its own detach and re-attach of an accessory switch
         * come back (phone_detach returns early for a phone already detached, its attach still due) */
        m->detach_at = m->attach_at = NONE_US;
        update_frames(m);
    } else if (!strcmp(name, "attach")) {
        m->detach_at = m->attach_at = NONE_US;
        phone_attach(m, 0); /* a phone plugged in starts in its normal mode */
        update_frames(m);
    } else if (!strcmp(name, "aoa") && (value == 0 || value == 1 || value == 2)) {
        m->aoa_version = (int)value;
    } else if (!strcmp(name, "packet") && value >= 1 && value <= MAXPKT && value == (int)value) {
        m->packet_size = (unsigned)value;
    } else if (!strcmp(name, "zlp") && (value == 0 || value == 1)) {
        m->zlp = (int)value;
    } else if (!strcmp(name, "osc") && (value == 0 || value == 1)) {
        m->dead_osc = value == 0;
    } else if (!strcmp(name, "never_switch") && (value == 0 || value == 1 || value == 2)) {
        m->never_switch = (int)value;
    } else if (!strcmp(name, "lost_ack") && value >= 0 && value <= 1e6 && value == (int)value) {
        m->lost_acks = (unsigned)value;
    } else if (!strcmp(name, "config_value") && value >= 0 && value <= 255 && value == (int)value) {
        m->cfg_normal[5] = m->cfg_accessory[5] = (uint8_t)value; /* byte 5 of the buffer: CFG_MAX long */
    } else if (!strcmp(name, "ep0_packet") && value >= 0 && value <= 255 && value == (int)value) {
        m->dev_normal[7] = m->dev_accessory[7] = (uint8_t)value;
    } else if (!strcmp(name, "clear_halt_nak") && (value == 0 || value == 1)) {
        m->clear_halt_nak = (int)value;
    } else if (!strcmp(name, "condet_after_reset") && value >= 0 && value <= 100000 && value == (int)value) {
        m->condet_after_reset_us = (unsigned)value;
    } else {
        return -1;
    }
    return 0;
}

int max3421e_descriptor(max3421e_t *m, int mode, int type, const uint8_t *bytes, size_t len)
{
    if ((mode != 1 && mode != 2) || (type != 1 && type != 2) || (len && !bytes))
        return -1;
    uint8_t *dst = type == 1 ? (mode == 1 ? m->dev_normal : m->dev_accessory)
                             : (mode == 1 ? m->cfg_normal : m->cfg_accessory);
    unsigned *dst_len = type == 1 ? (mode == 1 ? &m->dev_normal_len : &m->dev_accessory_len)
                                  : (mode == 1 ? &m->cfg_normal_len : &m->cfg_accessory_len);
    size_t cap = type == 1 ? MAXPKT : CFG_MAX;
    if (len > cap)
        return -1;
    memset(dst, 0, cap); /* bytes past len: never served, and byte 7 (bMaxPacketSize0) 0 if unsaid */
    memcpy(dst, bytes, len);
    *dst_len = (unsigned)len;
    return 0;
}

const char *max3421e_last_error(const max3421e_t *m) { return m->last_error; }
