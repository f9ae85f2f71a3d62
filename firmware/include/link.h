/*
 * link.h - the reliable-command answer cache and calibration reassembly (sans-IO, portable).
 *
 * Answer cache (docs/protocol.md, receiver rules; protocol.reliable.AnswerCache): a reliable command is
 * executed once and its answer remembered under (msg_id, seq) with a CRC of its payload; a frame with
 * RETRANSMIT, the same key and the same content gets the remembered answer again without running the
 * command twice. The last LINK_ANSWERS answers are kept; a Hello or a reset clears them.
 *
 * Reassembler (protocol/calibration/transfer.py): collects the CalibrationData fragments of one transfer
 * at a time into a buffer of `max_len` bytes, with the same checks and in the same order as the Python.
 * Repeats of the transfer just completed are harmless duplicates until reasm_forget.
 */
#ifndef LINK_H
#define LINK_H

#include <stdint.h>

#include "calib.h"
#include "frame.h"

#define LINK_ANSWERS 32u
#define ANSWER_ACK 0u /* else a NACK_REASON_* */

typedef struct {
    uint8_t msg_id, seq, len, answer, used;
    uint16_t crc;
} answer_t;

typedef struct {
    answer_t entries[LINK_ANSWERS];
    uint8_t next;
} answer_cache_t;

void answers_forget(answer_cache_t *c);
/* 1 and *answer set if `f` is a retransmission of a command already answered, else 0. */
uint8_t answers_lookup(const answer_cache_t *c, const frame_t *f, uint8_t *answer);
void answers_remember(answer_cache_t *c, const frame_t *f, uint8_t answer);

#define REASM_MAX_FRAGMENTS ((CAL_MAX_SIZE + MAX_CALIBRATION_CHUNK - 1u) / MAX_CALIBRATION_CHUNK)

typedef struct {
    uint8_t unit, transfer_id, count;
    uint16_t total_len, set_crc;
} reasm_header_t;

typedef enum {
    REASM_PENDING = 0, /* accepted, more fragments to come (or a harmless repeat) */
    REASM_DONE,        /* the set is complete and its CRC checks: buf[0..total_len) */
    REASM_TOO_LONG,    /* total_len larger than this receiver takes */
    REASM_BAD_COUNT,   /* count does not fit total_len */
    REASM_BAD_INDEX,   /* index not below count */
    REASM_BAD_CHUNK,   /* chunk of the wrong size */
    REASM_CONTRADICTS, /* header differs from the transfer's, or a repeat carries different bytes */
    REASM_BAD_CRC      /* the finished set's CRC differs from set_crc */
} reasm_status_t;

typedef struct {
    uint16_t max_len;
    uint8_t active, have_done;
    uint8_t held; /* bit i: fragment i received */
    reasm_header_t header, done;
    uint8_t buf[CAL_MAX_SIZE];
} reassembler_t;

void reasm_init(reassembler_t *r, uint16_t max_len);
void reasm_reset(reassembler_t *r); /* forget an unfinished transfer */
/* Forget every transfer, the one just completed too (its repeat is then judged anew): after refusing the
 * set reasm_feed completed, and at a new session (a restarted host numbers its transfers from 1 again). */
void reasm_forget(reassembler_t *r);
reasm_status_t reasm_feed(reassembler_t *r, const calibration_data_t *m);

#endif /* LINK_H */
