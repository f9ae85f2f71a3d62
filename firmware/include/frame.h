/*
 * frame.h - frames on the wire (the C twin of protocol/frame.py). Sans-IO: bytes in, events out.
 *
 * Unencoded frame, all fields little-endian:
 *   offset 0 version (PROTOCOL_VERSION), 1 msg_id, 2 seq, 3 flags, 4.. payload (0..250 bytes),
 *   then CRC-16/CCITT-FALSE over everything before it.
 * On the wire: COBS(frame) + 0x00. A corrupt frame costs that frame only: the deframer resynchronises at
 * the next delimiter, and counts what it saw exactly like protocol.frame.Deframer.
 */
#ifndef FRAME_H
#define FRAME_H

#include <stdint.h>

#include "protocol_gen.h"

/* A decoded, valid frame. */
typedef struct {
    uint8_t msg_id;
    uint8_t seq;
    uint8_t flags;
    uint8_t payload_len;
    const uint8_t *payload; /* raw payload bytes (inside the deframer's buffer, valid until the next feed) */
    msg_any_t msg;          /* the decoded message */
} frame_t;

typedef struct {
    uint32_t bytes;
    uint32_t frames;
    uint32_t bad[BAD_FRAME_REASONS + 1]; /* by reason (index 0 unused) */
    uint32_t bad_total;
    uint32_t resyncs;
    uint32_t seq_gaps;
    uint32_t duplicates;
} link_counters_t;

typedef struct {
    uint8_t buf[FRAME_MAX_ENCODED];
    uint16_t len;
    uint8_t skipping; /* an over-long chunk was dropped: ignore bytes up to the next delimiter */
    uint8_t have_seq;
    uint8_t last_seq;
    uint8_t last_bad; /* reason of the last bad frame (0: none yet) */
    wire_where_t last_where;
    link_counters_t counters;
} deframer_t;

typedef enum { DEFRAME_NONE = 0, DEFRAME_FRAME, DEFRAME_BAD } deframe_event_t;

void deframer_init(deframer_t *d);
/* Forget a partial frame and the sequence history (after a reconnect); counters are kept. */
void deframer_reset(deframer_t *d);
/* One byte in. DEFRAME_FRAME fills *out; DEFRAME_BAD leaves the reason in d->last_bad. */
deframe_event_t deframer_feed(deframer_t *d, uint8_t byte, frame_t *out);

/* Decode one COBS chunk (no delimiter) in place: 0 and *out filled, or a BAD_FRAME_* reason. */
uint8_t frame_decode(uint8_t *chunk, uint16_t len, frame_t *out, wire_where_t *where);

/* Longest wire form of a frame: COBS of header + payload + CRC, plus the delimiter. */
#define FRAME_MAX_WIRE (FRAME_MAX_ENCODED + 1u)

/* Encode `msg` (a struct of message `msg_id`) as wire bytes into `out` (FRAME_MAX_WIRE bytes).
 * Returns the wire length, or 0 if a field is out of range (the frame is not sent). */
uint16_t frame_encode(uint8_t msg_id, uint8_t seq, uint8_t flags, const void *msg, uint8_t *out);

#endif /* FRAME_H */
