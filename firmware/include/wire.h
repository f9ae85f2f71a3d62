/*
 * wire.h - table-driven codec for message payloads (the C twin of protocol/fields.py).
 *
 * Every message and record of the catalogue has a C struct and a field table, both generated from the
 * Python catalogue into protocol_gen.h / protocol_gen.c (python -m firmware_sim.avr.codegen). This file
 * is the one piece of code that walks those tables: it decodes a payload into a struct and encodes a
 * struct into a payload, checking every range both ways exactly as protocol/fields.py does, so the
 * board refuses what the Python host would refuse and for the same reason.
 *
 * Sans-IO and portable: compiles for the AVR (tables in flash) and for the host (tests).
 *
 * Field kinds and their C storage:
 *   scalar  u8 u16 u32 i8 i16 i32 f32 enum8   native type at `offset`
 *   text    struct { uint8_t len; char s[max]; }   len at `offset`, bytes at `data_offset`
 *   blob    struct { uint8_t len; uint8_t b[max]; }
 *   array   struct { uint8_t count; T items[max]; } count at `offset`, items at `data_offset`,
 *           each `elem_size` bytes; T is a scalar (`elem`) or a record (`record`, a layout index)
 */
#ifndef WIRE_H
#define WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "flash.h"

enum wire_kind {
    WIRE_U8 = 0,
    WIRE_U16,
    WIRE_U32,
    WIRE_I8,
    WIRE_I16,
    WIRE_I32,
    WIRE_F32,
    WIRE_ENUM8, /* a u8 that must be one of a set of values (bit mask, values < 32) */
    WIRE_TEXT,  /* u8 byte count + UTF-8 bytes */
    WIRE_BLOB,  /* u8 byte count + bytes */
    WIRE_ARRAY, /* u8 element count + elements (scalars or records) */
    WIRE_RECORD /* only as an array's element kind */
};

/* Inclusive range of a scalar (or of an array's scalar elements); ENUM8 uses `mask`. */
typedef union {
    struct {
        uint32_t lo, hi;
    } u;
    struct {
        int32_t lo, hi;
    } i;
    struct {
        float lo, hi;
    } f;
    uint32_t mask;
} wire_range_t;

typedef struct {
    uint8_t kind;         /* enum wire_kind */
    uint8_t elem;         /* WIRE_ARRAY: element kind (a scalar kind or WIRE_RECORD) */
    uint8_t record;       /* WIRE_ARRAY of records: index into wire_records[] */
    uint8_t run_len;      /* first scalar of a run of consecutive scalars: the run's wire bytes, else 0 */
    uint16_t offset;      /* offsetof the value, or of the len/count byte */
    uint16_t data_offset; /* TEXT/BLOB/ARRAY: offsetof the bytes or items */
    uint16_t elem_size;   /* ARRAY: sizeof one C element */
    uint8_t min_count;    /* ARRAY: fewest elements */
    uint8_t max_count;    /* ARRAY: most elements; TEXT/BLOB: most bytes */
    wire_range_t range;   /* scalars and scalar elements */
} wire_field_t;

typedef struct {
    const wire_field_t *fields; /* in flash on the AVR */
    uint8_t n_fields;
    uint16_t c_size; /* sizeof the C struct */
} wire_layout_t;

/* Why a payload did not decode (the subset of protocol.frame.BadFrameReason a payload can cause). */
typedef enum {
    WIRE_OK = 0,
    WIRE_LENGTH,     /* the payload ends inside a field, or has trailing bytes */
    WIRE_FIELD_RANGE /* a value outside its range, a bad count, invalid UTF-8 */
} wire_status_t;

/* Where decoding or encoding failed: the field index in its layout (and the element for arrays). */
typedef struct {
    uint8_t field;
    uint8_t element; /* 0xFF: not inside an array */
} wire_where_t;

/* Decode `len` payload bytes into `out` (zeroed first). Trailing bytes are a WIRE_LENGTH error. */
wire_status_t wire_decode(const wire_layout_t *layout, const uint8_t *payload, uint16_t len, void *out,
                          wire_where_t *where);

/* Encode `msg` into `out` (room for `cap` bytes); *len receives the payload size. A value outside its
 * range (or a payload longer than cap) is refused with WIRE_FIELD_RANGE / WIRE_LENGTH. */
wire_status_t wire_encode(const wire_layout_t *layout, const void *msg, uint8_t *out, uint16_t cap,
                          uint16_t *len, wire_where_t *where);

/* Strict UTF-8 check (as Python's bytes.decode("utf-8")): no overlongs, surrogates or > U+10FFFF. */
int wire_utf8_valid(const uint8_t *s, uint16_t n);

/* Little-endian helpers (the wire's byte order), usable on any host. */
static inline uint16_t wire_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static inline uint32_t wire_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static inline void wire_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}
static inline void wire_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

#endif /* WIRE_H */
