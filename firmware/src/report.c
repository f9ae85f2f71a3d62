/*
 * report.c - everything the board sends: frames through the transmit ring, numbered per sender.
 *
 * Outgoing messages are built in one static buffer (they are large: a HelloReply is ~240 bytes, and the
 * stack must stay small) and encoded into another; a frame that finds the transmit ring full is dropped
 * and counted (board.tx_dropped), as firmware_sim's link does.
 *
 * What is sent again anyway yields to what is said once: telemetry and heartbeats (the next one is
 * newer) and download fragments (retried until acknowledged) are not queued into the last
 * SAID_ONCE_ROOM bytes of the ring, which stay for answers (Ack, Nack, HelloReply) and Logs. Before, six
 * units' telemetry and a download kept the 1 KiB ring full at 115200 baud, and a Hello found no room
 * for its reply (tests/test_firmware_differential.py: the emulator's 64 KiB answered it).
 */
#include <avr/pgmspace.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "app.h"
#include "clock.h"
#include "flash.h"
#include "port.h"
#include "pulses.h"
#include "storage.h"
#include "uart.h"

#ifndef FIRMWARE_BUILD
#define FIRMWARE_BUILD "unknown"
#endif

static msg_any_t out;
static uint8_t wire[FRAME_MAX_WIRE];

#define SAID_ONCE_ROOM (FRAME_MAX_WIRE + 64u) /* a HelloReply, or a Log, and a few Acks */

static uint8_t sent_again(uint8_t msg_id)
{
    return msg_id == MSG_TELEMETRY || msg_id == MSG_HEARTBEAT || msg_id == MSG_CALIBRATION_DATA;
}

void report_name(const char *names_flash, uint8_t value, char *dst, unsigned n)
{
    flash_pick(names_flash, value, dst, n);
}

/* seq < 0: the next sequence number; else a retransmission of that one. */
void report_send(uint8_t msg_id, const void *msg, uint8_t flags, int16_t seq)
{
    uint8_t s;
    if (seq < 0) {
        s = board.tx_seq++;
    } else {
        s = (uint8_t)seq;
        flags |= FLAGS_RETRANSMIT;
    }
    if ((msg_id == MSG_TELEMETRY || msg_id == MSG_HEARTBEAT) && port_holds_reports())
        return; /* USB and no accessory open: stale on arrival (port.h); its number is a gap the host sees */
    if (msg_is_reliable(msg_id))
        flags |= FLAGS_ACK_REQUESTED;
    uint16_t n = frame_encode(msg_id, s, flags, msg, wire);
    if (!n || (sent_again(msg_id) && uart_tx_free() < n + SAID_ONCE_ROOM) || !port_send(wire, n))
        board.tx_dropped++;
}

void report_log(uint8_t severity, uint16_t code, const char *fmt_flash, ...)
{
    log_t *m = &out.log;
    memset(m, 0, sizeof *m);
    m->severity = severity;
    m->code = code;
    va_list ap;
    va_start(ap, fmt_flash);
    int n = vsnprintf_P(m->text.s, sizeof m->text.s, fmt_flash, ap);
    va_end(ap);
    m->text.len = (uint8_t)(n < 0 ? 0 : (n >= (int)sizeof m->text.s ? sizeof m->text.s - 1u : (unsigned)n));
    report_send(MSG_LOG, m, 0, -1);
}

/*
 * The uptime a message carries never goes back within a boot: a message stamped with a fresh clock read
 * (a state change's heartbeat) may be followed, in the same main-loop pass, by one stamped with the pass's
 * start, a millisecond earlier — and a host takes an uptime that went back for a reset (a closed loop
 * through the firmware saw a false POWER_ON reset that way). Wrap-aware: 2^32 ms is 49.7 days.
 */
static uint32_t last_stamp;

static uint32_t stamp(uint32_t now)
{
    if ((int32_t)(now - last_stamp) > 0)
        last_stamp = now;
    return last_stamp;
}

void report_heartbeat(uint32_t now)
{
    heartbeat_t *m = &out.heartbeat;
    m->time_ms = stamp(now);
    m->state = board.state;
    m->boot_id = board.boot_id;
    report_send(MSG_HEARTBEAT, m, 0, -1);
}

static void text_flash(uint8_t *len, char *dst, const char *src_flash, uint8_t max)
{
    strncpy_P(dst, src_flash, max);
    *len = (uint8_t)strnlen(dst, max);
}

void report_hello_reply(void)
{
    hello_reply_t *m = &out.hello_reply;
    memset(m, 0, sizeof *m);
    m->protocol_version = PROTOCOL_VERSION;
    m->schema_hash = SCHEMA_HASH;
    m->reset_cause = board.reset_cause;
    m->state = board.state;
    m->n_units = board.cfg.n_units;
    m->frame_rate_hz = (uint16_t)lrintf(board.cfg.frame_rate_hz);
    m->boot_id = board.boot_id;
    text_flash(&m->manufacturer.len, m->manufacturer.s, PSTR(IDENTITY_MANUFACTURER),
               HELLO_REPLY_MANUFACTURER_MAX_LEN);
    text_flash(&m->model.len, m->model.s, PSTR(IDENTITY_MODEL), HELLO_REPLY_MODEL_MAX_LEN);
    text_flash(&m->description.len, m->description.s, PSTR(IDENTITY_DESCRIPTION),
               HELLO_REPLY_DESCRIPTION_MAX_LEN);
    text_flash(&m->version.len, m->version.s, PSTR(IDENTITY_VERSION), HELLO_REPLY_VERSION_MAX_LEN);
    text_flash(&m->uri.len, m->uri.s, PSTR(IDENTITY_URI), HELLO_REPLY_URI_MAX_LEN);
    text_flash(&m->firmware_build.len, m->firmware_build.s, PSTR(FIRMWARE_BUILD),
               HELLO_REPLY_FIRMWARE_BUILD_MAX_LEN);
    m->serial.len = (uint8_t)strnlen(board.cfg.serial, HELLO_REPLY_SERIAL_MAX_LEN);
    memcpy(m->serial.s, board.cfg.serial, m->serial.len);
    report_send(MSG_HELLO_REPLY, m, 0, -1);
}

void report_answer(const frame_t *f, uint8_t answer)
{
    if (answer == ANSWER_ACK) {
        out.ack.msg_id = f->msg_id;
        out.ack.seq = f->seq;
        report_send(MSG_ACK, &out.ack, 0, -1);
    } else {
        out.nack.msg_id = f->msg_id;
        out.nack.seq = f->seq;
        out.nack.reason = answer;
        report_send(MSG_NACK, &out.nack, 0, -1);
    }
}

void report_cal_fragment(uint8_t index, uint8_t retry)
{
    download_t *d = &board.download;
    uint16_t len;
    const uint8_t *set = storage_cal(d->unit, &len);
    calibration_data_t *m = &out.calibration_data;
    uint16_t start = (uint16_t)index * MAX_CALIBRATION_CHUNK;
    if (!set || start >= len) /* never outside the set (an upload of its unit is BUSY meanwhile) */
        return;
    m->unit = d->unit;
    m->transfer_id = d->transfer_id;
    m->index = index;
    m->count = d->count;
    m->total_len = len;
    m->set_crc = d->set_crc;
    m->chunk.len = (uint8_t)(len - start < MAX_CALIBRATION_CHUNK ? len - start : MAX_CALIBRATION_CHUNK);
    memcpy(m->chunk.b, set + start, m->chunk.len);
    if (!retry)
        d->seq[index] = board.tx_seq;
    report_send(MSG_CALIBRATION_DATA, m, 0, retry ? (int16_t)d->seq[index] : -1);
}

static uint16_t clip16(uint32_t v) { return (uint16_t)(v > 0xFFFFu ? 0xFFFFu : v); }

static uint16_t fault_flags(void)
{
    uint16_t f = 0;
    if (board.link_lost)
        f |= FAULT_FLAG_LINK_LOST;
    if (board.power_state >= POWER_STATE_WARN)
        f |= FAULT_FLAG_BATTERY_LOW;
    if (board.ubec_over)
        f |= FAULT_FLAG_UBEC_OVERCURRENT;
    for (uint8_t u = 0; u < board.cfg.n_units; u++)
        if (storage_cal_source(u) == CAL_SOURCE_MISSING)
            f |= FAULT_FLAG_CALIBRATION_MISSING;
    if (board.reset_cause == RESET_CAUSE_WATCHDOG)
        f |= FAULT_FLAG_MCU_WATCHDOG_RESET;
    if (board.reset_cause == RESET_CAUSE_BROWN_OUT)
        f |= FAULT_FLAG_BROWN_OUT_RESET;
    if (board.clamped)
        f |= FAULT_FLAG_SETPOINT_CLAMPED;
    return f;
}

void report_telemetry(uint32_t now)
{
    telemetry_t *m = &out.telemetry;
    const link_counters_t *c = &board.deframer.counters;
    memset(m, 0, sizeof *m);
    m->time_ms = stamp(now);
    m->state = board.state;
    m->mode = esc_cal_active() ? CONTROL_MODE_ESC_CALIBRATION : board.mode;
    m->watchdog = board.link_lost ? WATCHDOG_STATE_LINK_LOST : WATCHDOG_STATE_OK;
    m->power = board.power_state;
    m->faults = fault_flags();
    m->link_age_ms = board.have_rx ? clip16(now - board.last_rx_ms) : 0xFFFFu;
    m->battery_mv = board.power.battery_mv;
    m->battery_ma = board.power.battery_ma;
    /* state of charge from the rest voltage: the loaded voltage plus the pack's I*R sag */
    float rest_v_cell = board.pm.filtered_v_cell + board.power.battery_ma * 0.001f *
                                                       board.cfg.battery_resistance_ohm /
                                                       (float)board.cfg.cells;
    long soc = lrintf(power_soc(rest_v_cell) * 100.0f);
    m->battery_soc = (uint8_t)(soc < 0 ? 0 : (soc > 100 ? 100 : soc));
    m->ubec_mv = board.power.ubec_mv;
    m->ubec_ma = board.power.ubec_ma;
    m->rx_frames = c->frames;
    m->rx_bad = c->bad_total;
    m->seq_gaps = c->seq_gaps;
    m->pulses_us.count = board.n_channels;
    memcpy(m->pulses_us.items, board.outputs, board.n_channels * sizeof board.outputs[0]);
    m->units.count = board.cfg.n_units;
    memcpy(m->units.items, board.units, board.cfg.n_units * sizeof board.units[0]);
    report_send(MSG_TELEMETRY, m, 0, -1);
}
