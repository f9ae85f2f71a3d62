/* frame.c - deframer and frame encoder (see frame.h). */
#include "frame.h"

#include <string.h>

#include "cobs.h"
#include "crc16.h"

void deframer_init(deframer_t *d) { memset(d, 0, sizeof *d); }

void deframer_reset(deframer_t *d)
{
    d->len = 0;
    d->skipping = 0;
    d->have_seq = 0;
}

uint8_t frame_decode(uint8_t *chunk, uint16_t len, frame_t *out, wire_where_t *where)
{
    if (len > FRAME_MAX_ENCODED)
        return BAD_FRAME_TOO_LONG;
    int16_t n = cobs_decode_in_place(chunk, len);
    if (n < 0)
        return BAD_FRAME_COBS;
    if (n < (int16_t)(FRAME_HEADER_SIZE + FRAME_CRC_SIZE))
        return BAD_FRAME_TOO_SHORT;
    if (n > (int16_t)FRAME_MAX_FRAME)
        return BAD_FRAME_TOO_LONG;
    uint16_t body = (uint16_t)n - FRAME_CRC_SIZE;
    if (crc16_update(CRC16_INIT, chunk, body) != wire_get_u16(chunk + body))
        return BAD_FRAME_CRC;
    if (chunk[0] != PROTOCOL_VERSION)
        return BAD_FRAME_VERSION;
    const wire_layout_t *layout = wire_layout_for(chunk[1]);
    if (!layout)
        return BAD_FRAME_UNKNOWN_ID;
    out->msg_id = chunk[1];
    out->seq = chunk[2];
    out->flags = chunk[3];
    out->payload = chunk + FRAME_HEADER_SIZE;
    out->payload_len = (uint8_t)(body - FRAME_HEADER_SIZE);
    switch (wire_decode(layout, out->payload, out->payload_len, &out->msg, where)) {
    case WIRE_OK:
        return 0;
    case WIRE_LENGTH:
        return BAD_FRAME_LENGTH;
    default:
        return BAD_FRAME_FIELD_RANGE;
    }
}

static deframe_event_t bad(deframer_t *d, uint8_t reason)
{
    d->last_bad = reason;
    d->counters.bad[reason]++;
    d->counters.bad_total++;
    return DEFRAME_BAD;
}

deframe_event_t deframer_feed(deframer_t *d, uint8_t byte, frame_t *out)
{
    d->counters.bytes++;
    if (byte != 0) {
        if (d->skipping)
            return DEFRAME_NONE;
        if (d->len < FRAME_MAX_ENCODED) {
            d->buf[d->len++] = byte;
            return DEFRAME_NONE;
        }
        /* More than FRAME_MAX_ENCODED bytes without a delimiter: drop them, resync at the next one. */
        d->len = 0;
        d->skipping = 1;
        d->counters.resyncs++;
        return bad(d, BAD_FRAME_TOO_LONG);
    }
    uint16_t len = d->len;
    d->len = 0;
    if (d->skipping) {
        d->skipping = 0;
        return DEFRAME_NONE;
    }
    if (len == 0)
        return DEFRAME_NONE; /* idle fill between frames */
    uint8_t reason = frame_decode(d->buf, len, out, &d->last_where);
    if (reason)
        return bad(d, reason);
    /* A Hello begins its sender's numbering afresh (a restarted host numbers from 0 again): the step to
     * it is neither a gap nor a duplicate (protocol/frame.py's Deframer(renumbered_by), docs/protocol.md). */
    if (d->have_seq && out->msg_id != MSG_HELLO) {
        uint8_t step = (uint8_t)(out->seq - d->last_seq);
        if (step == 0)
            d->counters.duplicates++;
        else if (step > 1)
            d->counters.seq_gaps += (uint32_t)(step - 1);
    }
    d->have_seq = 1;
    d->last_seq = out->seq;
    d->counters.frames++;
    return DEFRAME_FRAME;
}

uint16_t frame_encode(uint8_t msg_id, uint8_t seq, uint8_t flags, const void *msg, uint8_t *out)
{
    /* The unencoded frame is built at the end of `out` and COBS-encoded to its start: COBS output never
     * overtakes its input when the input sits (overhead) bytes further on. */
    const wire_layout_t *layout = wire_layout_for(msg_id);
    if (!layout)
        return 0;
    uint8_t *body = out + (FRAME_MAX_WIRE - FRAME_MAX_FRAME);
    body[0] = PROTOCOL_VERSION;
    body[1] = msg_id;
    body[2] = seq;
    body[3] = flags;
    uint16_t plen;
    if (wire_encode(layout, msg, body + FRAME_HEADER_SIZE, FRAME_MAX_PAYLOAD, &plen, NULL) != WIRE_OK)
        return 0;
    uint16_t n = (uint16_t)(FRAME_HEADER_SIZE + plen);
    wire_put_u16(body + n, crc16_update(CRC16_INIT, body, n));
    n = (uint16_t)(n + FRAME_CRC_SIZE);
    uint16_t enc = cobs_encode(body, n, out);
    out[enc] = 0;
    return (uint16_t)(enc + 1);
}
