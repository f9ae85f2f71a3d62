/*
 * host_api.c - a flat API over the firmware's portable modules for the host library
 * (build/libfirmware-host.so), so the tests drive the very C code the board runs through ctypes
 * (firmware_sim/avr/hostlib.py) and compare it with the Python reference. Not built for the AVR.
 */
#include <stdlib.h>
#include <string.h>

#include "calib.h"
#include "config.h"
#include "frame.h"
#include "link.h"
#include "power.h"
#include "state.h"

/* ------------------------------------------------------------------ deframer */
typedef struct {
    deframer_t d;
    frame_t f;
} host_deframer_t;

void *host_deframer_new(void);
void host_deframer_free(void *h);
long host_deframer_feed(void *h, const uint8_t *data, uint32_t n, uint8_t *out, uint32_t cap);
void host_deframer_counters(void *h, uint32_t *out);
void host_deframer_reset(void *h);
long host_reencode(const uint8_t *chunk, uint16_t len, uint8_t *out, uint8_t *reason);

void *host_deframer_new(void)
{
    host_deframer_t *h = calloc(1, sizeof *h);
    if (h)
        deframer_init(&h->d);
    return h;
}

void host_deframer_free(void *h) { free(h); }

void host_deframer_reset(void *h) { deframer_reset(&((host_deframer_t *)h)->d); }

/* Feed n bytes; the events go to `out` as records:
 *   0x01, msg_id, seq, flags, wire_len (u16 LE), wire bytes re-encoded from the decoded message
 *   0x02, reason
 * Returns the bytes written, or -1 if `out` is too small. */
long host_deframer_feed(void *p, const uint8_t *data, uint32_t n, uint8_t *out, uint32_t cap)
{
    host_deframer_t *h = p;
    uint32_t at = 0;
    uint8_t wire[FRAME_MAX_WIRE];
    for (uint32_t i = 0; i < n; i++) {
        deframe_event_t ev = deframer_feed(&h->d, data[i], &h->f);
        if (ev == DEFRAME_FRAME) {
            uint16_t len = frame_encode(h->f.msg_id, h->f.seq, h->f.flags, &h->f.msg, wire);
            if (at + 6u + len > cap)
                return -1;
            out[at++] = 1;
            out[at++] = h->f.msg_id;
            out[at++] = h->f.seq;
            out[at++] = h->f.flags;
            wire_put_u16(out + at, len);
            at += 2;
            memcpy(out + at, wire, len);
            at += len;
        } else if (ev == DEFRAME_BAD) {
            if (at + 2u > cap)
                return -1;
            out[at++] = 2;
            out[at++] = h->d.last_bad;
        }
    }
    return (long)at;
}

/* frames, bad_total, resyncs, seq_gaps, duplicates, bytes, then bad[1..BAD_FRAME_REASONS] */
void host_deframer_counters(void *p, uint32_t *out)
{
    const link_counters_t *c = &((host_deframer_t *)p)->d.counters;
    out[0] = c->frames;
    out[1] = c->bad_total;
    out[2] = c->resyncs;
    out[3] = c->seq_gaps;
    out[4] = c->duplicates;
    out[5] = c->bytes;
    for (uint8_t r = 1; r <= BAD_FRAME_REASONS; r++)
        out[5 + r] = c->bad[r];
}

/* ------------------------------------------------------------------ reassembler */
void *host_reasm_new(uint16_t max_len);
int host_reasm_feed(void *r, uint8_t unit, uint8_t transfer_id, uint8_t index, uint8_t count,
                    uint16_t total_len, uint16_t set_crc, const uint8_t *chunk, uint8_t chunk_len);
const uint8_t *host_reasm_buf(void *r);

void *host_reasm_new(uint16_t max_len)
{
    reassembler_t *r = malloc(sizeof *r);
    if (r)
        reasm_init(r, max_len);
    return r;
}

int host_reasm_feed(void *r, uint8_t unit, uint8_t transfer_id, uint8_t index, uint8_t count,
                    uint16_t total_len, uint16_t set_crc, const uint8_t *chunk, uint8_t chunk_len)
{
    calibration_data_t m;
    memset(&m, 0, sizeof m);
    m.unit = unit;
    m.transfer_id = transfer_id;
    m.index = index;
    m.count = count;
    m.total_len = total_len;
    m.set_crc = set_crc;
    m.chunk.len = chunk_len;
    memcpy(m.chunk.b, chunk, chunk_len);
    return reasm_feed(r, &m);
}

const uint8_t *host_reasm_buf(void *r) { return ((reassembler_t *)r)->buf; }

/* ------------------------------------------------------------------ answer cache */
void *host_answers_new(void);
int host_answers_lookup(void *c, uint8_t msg_id, uint8_t seq, uint8_t flags, const uint8_t *payload,
                        uint8_t len);
void host_answers_remember(void *c, uint8_t msg_id, uint8_t seq, const uint8_t *payload, uint8_t len,
                           uint8_t answer);

void *host_answers_new(void) { return calloc(1, sizeof(answer_cache_t)); }

static frame_t frame_of(uint8_t msg_id, uint8_t seq, uint8_t flags, const uint8_t *payload, uint8_t len)
{
    frame_t f;
    memset(&f, 0, sizeof f);
    f.msg_id = msg_id;
    f.seq = seq;
    f.flags = flags;
    f.payload = payload;
    f.payload_len = len;
    return f;
}

/* -1: execute it; else the remembered answer */
int host_answers_lookup(void *c, uint8_t msg_id, uint8_t seq, uint8_t flags, const uint8_t *payload,
                        uint8_t len)
{
    frame_t f = frame_of(msg_id, seq, flags, payload, len);
    uint8_t answer;
    return answers_lookup(c, &f, &answer) ? answer : -1;
}

void host_answers_remember(void *c, uint8_t msg_id, uint8_t seq, const uint8_t *payload, uint8_t len,
                           uint8_t answer)
{
    frame_t f = frame_of(msg_id, seq, 0, payload, len);
    answers_remember(c, &f, answer);
}

/* ------------------------------------------------------------------ configuration */
int host_config_parse(const uint8_t *block, float *numbers, char *serial, uint8_t *problem);

/* numbers: n_units, frame_rate_hz, telemetry_rate_hz, heartbeat_rate_hz, link_timeout_ms, mcu_watchdog_ms,
 * rotor_safe_us, ppm, cells, warn_v_cell, limit_v_cell, shed_v_cell, baud, esc_supply_switch, link */
int host_config_parse(const uint8_t *block, float *numbers, char *serial, uint8_t *problem)
{
    board_config_t c;
    config_status_t st = config_parse(block, &c, problem);
    float v[] = {c.n_units,         c.frame_rate_hz,   c.telemetry_rate_hz, c.heartbeat_rate_hz,
                 c.link_timeout_ms, c.mcu_watchdog_ms, c.rotor_safe_us,     c.ppm,
                 c.cells,           c.warn_v_cell,     c.limit_v_cell,      c.shed_v_cell,
                 (float)c.baud,     c.esc_supply_switch, c.link};
    memcpy(numbers, v, sizeof v);
    strcpy(serial, c.serial);
    return st;
}
