/* link.c - answer cache and calibration reassembly (see link.h). */
#include "link.h"

#include <string.h>

#include "crc16.h"

void answers_forget(answer_cache_t *c) { memset(c, 0, sizeof *c); }

static answer_t *find(const answer_cache_t *c, const frame_t *f)
{
    for (uint8_t i = 0; i < LINK_ANSWERS; i++) {
        const answer_t *e = &c->entries[i];
        if (e->used && e->msg_id == f->msg_id && e->seq == f->seq)
            return (answer_t *)e;
    }
    return 0;
}

uint8_t answers_lookup(const answer_cache_t *c, const frame_t *f, uint8_t *answer)
{
    if (!(f->flags & FLAGS_RETRANSMIT))
        return 0;
    const answer_t *e = find(c, f);
    if (!e || e->len != f->payload_len || e->crc != crc16_update(CRC16_INIT, f->payload, f->payload_len))
        return 0; /* a different command reusing the key: execute it anew */
    *answer = e->answer;
    return 1;
}

/* The cache is a ring in the order answers were given: `next` is the oldest slot (the next overwritten),
 * the slot before it the newest. An answer given again to a key already held (the host's sequence numbers
 * wrapped, the same command id reused) becomes the newest, as the emulator's ordered dict moves it: left
 * in its old slot it was overwritten up to 31 answers early, and a late retransmission of an Arm the
 * board had answered since was carried out again (a disarmed board armed). The entries after it move down
 * one slot, in order. */
void answers_remember(answer_cache_t *c, const frame_t *f, uint8_t answer)
{
    answer_t *e = find(c, f);
    if (e) {
        uint8_t i = (uint8_t)(e - c->entries);
        uint8_t newest = (uint8_t)((c->next + LINK_ANSWERS - 1u) % LINK_ANSWERS);
        while (i != newest) {
            uint8_t after = (uint8_t)((i + 1u) % LINK_ANSWERS);
            c->entries[i] = c->entries[after];
            i = after;
        }
        e = &c->entries[newest];
    } else {
        e = &c->entries[c->next];
        c->next = (uint8_t)((c->next + 1u) % LINK_ANSWERS);
    }
    e->used = 1;
    e->msg_id = f->msg_id;
    e->seq = f->seq;
    e->len = f->payload_len;
    e->crc = crc16_update(CRC16_INIT, f->payload, f->payload_len);
    e->answer = answer;
}

/* ------------------------------------------------------------------------------ reassembly */
void reasm_init(reassembler_t *r, uint16_t max_len)
{
    memset(r, 0, sizeof *r);
    r->max_len = max_len > CAL_MAX_SIZE ? CAL_MAX_SIZE : max_len;
}

void reasm_reset(reassembler_t *r)
{
    r->active = 0;
    r->held = 0;
}

void reasm_forget(reassembler_t *r)
{
    reasm_reset(r);
    r->have_done = 0;
}

static reasm_header_t header_of(const calibration_data_t *m)
{
    reasm_header_t h = {m->unit, m->transfer_id, m->count, m->total_len, m->set_crc};
    return h;
}

static int same(const reasm_header_t *a, const reasm_header_t *b)
{
    return a->unit == b->unit && a->transfer_id == b->transfer_id && a->count == b->count &&
           a->total_len == b->total_len && a->set_crc == b->set_crc;
}

static reasm_status_t fail(reassembler_t *r, reasm_status_t why)
{
    reasm_reset(r);
    return why;
}

reasm_status_t reasm_feed(reassembler_t *r, const calibration_data_t *m)
{
    reasm_header_t h = header_of(m);
    if (r->have_done && same(&h, &r->done))
        return REASM_PENDING; /* a repeat of the set just completed */
    if (m->total_len > r->max_len)
        return fail(r, REASM_TOO_LONG);
    uint16_t want_count =
        m->total_len ? (uint16_t)((m->total_len + MAX_CALIBRATION_CHUNK - 1u) / MAX_CALIBRATION_CHUNK) : 1u;
    if (m->count != want_count)
        return fail(r, REASM_BAD_COUNT);
    if (m->index >= m->count)
        return fail(r, REASM_BAD_INDEX);
    uint16_t last = (uint16_t)(m->total_len - MAX_CALIBRATION_CHUNK * (m->count - 1u));
    uint16_t want = m->index == m->count - 1u ? last : MAX_CALIBRATION_CHUNK;
    if (m->chunk.len != want)
        return fail(r, REASM_BAD_CHUNK);
    if (!r->active || r->header.unit != m->unit || r->header.transfer_id != m->transfer_id) {
        r->active = 1;
        r->header = h;
        r->held = 0;
        r->have_done = 0;
    } else if (!same(&h, &r->header)) {
        return fail(r, REASM_CONTRADICTS);
    }
    uint8_t *dst = r->buf + (uint16_t)m->index * MAX_CALIBRATION_CHUNK;
    uint8_t bit = (uint8_t)(1u << m->index);
    if (r->held & bit) {
        if (memcmp(dst, m->chunk.b, m->chunk.len) != 0)
            return fail(r, REASM_CONTRADICTS);
        return REASM_PENDING;
    }
    memcpy(dst, m->chunk.b, m->chunk.len);
    r->held |= bit;
    if (r->held != (uint8_t)((1u << m->count) - 1u))
        return REASM_PENDING;
    reasm_reset(r);
    if (crc16_update(CRC16_INIT, r->buf, h.total_len) != h.set_crc)
        return REASM_BAD_CRC;
    r->done = h;
    r->have_done = 1;
    return REASM_DONE;
}
