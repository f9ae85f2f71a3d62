/*
 * wire.c - walks the generated field tables to decode and encode payloads (see wire.h).
 *
 * The order of checks follows protocol/fields.py so that the C and Python ends give the same verdict
 * on the same bytes: a run of consecutive fixed-size scalars is first checked for length as a whole,
 * then each value for range; a variable field reads its count, checks it, then its contents.
 */
#include "wire.h"

#include <string.h>

#include "protocol_gen.h"

typedef union {
    uint32_t u;
    int32_t i;
    float f;
} wire_value_t;

static uint8_t scalar_size(uint8_t kind)
{
    switch (kind) {
    case WIRE_U16:
    case WIRE_I16:
        return 2;
    case WIRE_U32:
    case WIRE_I32:
    case WIRE_F32:
        return 4;
    default:
        return 1;
    }
}

/* Wire bytes -> value (sign-extended for signed kinds). */
static wire_value_t scalar_read(uint8_t kind, const uint8_t *p)
{
    wire_value_t v;
    switch (kind) {
    case WIRE_U16:
        v.u = wire_get_u16(p);
        break;
    case WIRE_I8:
        v.i = (int8_t)p[0];
        break;
    case WIRE_I16:
        v.i = (int16_t)wire_get_u16(p);
        break;
    case WIRE_U32:
    case WIRE_I32:
    case WIRE_F32:
        v.u = wire_get_u32(p); /* the float's bit pattern: both ends are IEEE-754 little-endian */
        break;
    default:
        v.u = p[0];
        break;
    }
    return v;
}

static int scalar_ok(uint8_t kind, const wire_range_t *r, wire_value_t v)
{
    switch (kind) {
    case WIRE_I8:
    case WIRE_I16:
    case WIRE_I32:
        return v.i >= r->i.lo && v.i <= r->i.hi;
    case WIRE_F32:
        return v.f >= r->f.lo && v.f <= r->f.hi; /* false for NaN; the bounds are finite */
    case WIRE_ENUM8:
        return v.u < 32 && ((r->mask >> v.u) & 1u);
    default:
        return v.u >= r->u.lo && v.u <= r->u.hi;
    }
}

/* C storage <-> value. */
static void scalar_store(uint8_t kind, uint8_t *dst, wire_value_t v)
{
    switch (kind) {
    case WIRE_U16:
    case WIRE_I16: {
        uint16_t x = (uint16_t)v.u;
        memcpy(dst, &x, 2);
        break;
    }
    case WIRE_U32:
    case WIRE_I32:
    case WIRE_F32:
        memcpy(dst, &v.u, 4);
        break;
    default:
        *dst = (uint8_t)v.u;
        break;
    }
}

static wire_value_t scalar_load(uint8_t kind, const uint8_t *src)
{
    wire_value_t v;
    switch (kind) {
    case WIRE_U16: {
        uint16_t x;
        memcpy(&x, src, 2);
        v.u = x;
        break;
    }
    case WIRE_I16: {
        int16_t x;
        memcpy(&x, src, 2);
        v.i = x;
        break;
    }
    case WIRE_I8:
        v.i = (int8_t)*src;
        break;
    case WIRE_U32:
    case WIRE_I32:
    case WIRE_F32:
        memcpy(&v.u, src, 4);
        break;
    default:
        v.u = *src;
        break;
    }
    return v;
}

static void scalar_write(uint8_t kind, uint8_t *p, wire_value_t v)
{
    switch (scalar_size(kind)) {
    case 2:
        wire_put_u16(p, (uint16_t)v.u);
        break;
    case 4:
        wire_put_u32(p, v.u);
        break;
    default:
        p[0] = (uint8_t)v.u;
        break;
    }
}

int wire_utf8_valid(const uint8_t *s, uint16_t n)
{
    uint16_t i = 0;
    while (i < n) {
        uint8_t c = s[i];
        uint8_t more;
        uint32_t cp;
        if (c < 0x80) {
            i++;
            continue;
        } else if (c >= 0xC2 && c <= 0xDF) {
            more = 1;
            cp = c & 0x1F;
        } else if (c >= 0xE0 && c <= 0xEF) {
            more = 2;
            cp = c & 0x0F;
        } else if (c >= 0xF0 && c <= 0xF4) {
            more = 3;
            cp = c & 0x07;
        } else {
            return 0; /* continuation byte, overlong lead C0/C1, or F5..FF */
        }
        if ((uint16_t)(n - i) <= more)
            return 0;
        for (uint8_t k = 1; k <= more; k++) {
            uint8_t cc = s[i + k];
            if ((cc & 0xC0) != 0x80)
                return 0;
            cp = (cp << 6) | (cc & 0x3F);
        }
        if ((more == 2 && (cp < 0x800 || (cp >= 0xD800 && cp <= 0xDFFF))) ||
            (more == 3 && (cp < 0x10000 || cp > 0x10FFFF)))
            return 0;
        i += (uint16_t)(more + 1);
    }
    return 1;
}

static void read_field(const wire_field_t *src, wire_field_t *f) { flash_read(f, src, sizeof *f); }

static void read_layout(const wire_layout_t *src, wire_layout_t *l) { flash_read(l, src, sizeof *l); }

/* Decode one layout (message or record) starting at *pos. */
static wire_status_t decode_layout(const wire_layout_t *layout_flash, const uint8_t *buf, uint16_t len,
                                   uint16_t *pos, uint8_t *out, wire_where_t *where, uint8_t element)
{
    wire_layout_t layout;
    read_layout(layout_flash, &layout);
    for (uint8_t i = 0; i < layout.n_fields; i++) {
        wire_field_t f;
        read_field(&layout.fields[i], &f);
        where->field = i;
        where->element = element;
        if (f.kind <= WIRE_ENUM8) {
            if (f.run_len && (uint32_t)*pos + f.run_len > len)
                return WIRE_LENGTH;
            wire_value_t v = scalar_read(f.kind, buf + *pos);
            *pos += scalar_size(f.kind);
            if (!scalar_ok(f.kind, &f.range, v))
                return WIRE_FIELD_RANGE;
            scalar_store(f.kind, out + f.offset, v);
            continue;
        }
        if (*pos >= len)
            return WIRE_LENGTH;
        uint8_t n = buf[(*pos)++];
        if (f.kind == WIRE_TEXT || f.kind == WIRE_BLOB) {
            if ((uint32_t)*pos + n > len)
                return WIRE_LENGTH;
            if (f.kind == WIRE_TEXT && !wire_utf8_valid(buf + *pos, n))
                return WIRE_FIELD_RANGE;
            if (n > f.max_count)
                return WIRE_FIELD_RANGE;
            out[f.offset] = n;
            memcpy(out + f.data_offset, buf + *pos, n);
            *pos += n;
            continue;
        }
        /* WIRE_ARRAY */
        if (n < f.min_count || n > f.max_count)
            return WIRE_FIELD_RANGE;
        out[f.offset] = n;
        if (f.elem == WIRE_RECORD) {
            for (uint8_t k = 0; k < n; k++) {
                wire_where_t inner;
                wire_status_t st = decode_layout(&wire_records[f.record], buf, len, pos,
                                                 out + f.data_offset + (uint16_t)k * f.elem_size, &inner, k);
                if (st != WIRE_OK) {
                    where->element = k;
                    return st;
                }
            }
            continue;
        }
        uint8_t size = scalar_size(f.elem);
        if ((uint32_t)*pos + (uint32_t)n * size > len)
            return WIRE_LENGTH;
        for (uint8_t k = 0; k < n; k++) {
            wire_value_t v = scalar_read(f.elem, buf + *pos);
            *pos += size;
            if (!scalar_ok(f.elem, &f.range, v)) {
                where->element = k;
                return WIRE_FIELD_RANGE;
            }
            scalar_store(f.elem, out + f.data_offset + (uint16_t)k * f.elem_size, v);
        }
    }
    return WIRE_OK;
}

wire_status_t wire_decode(const wire_layout_t *layout, const uint8_t *payload, uint16_t len, void *out,
                          wire_where_t *where)
{
    wire_layout_t l;
    wire_where_t ignored;
    if (!where)
        where = &ignored;
    read_layout(layout, &l);
    memset(out, 0, l.c_size);
    where->field = 0;
    where->element = 0xFF;
    uint16_t pos = 0;
    wire_status_t st = decode_layout(layout, payload, len, &pos, (uint8_t *)out, where, 0xFF);
    if (st == WIRE_OK && pos != len) {
        where->field = l.n_fields;
        return WIRE_LENGTH;
    }
    return st;
}

static wire_status_t encode_layout(const wire_layout_t *layout_flash, const uint8_t *msg, uint8_t *out,
                                   uint16_t cap, uint16_t *pos, wire_where_t *where, uint8_t element)
{
    wire_layout_t layout;
    read_layout(layout_flash, &layout);
    for (uint8_t i = 0; i < layout.n_fields; i++) {
        wire_field_t f;
        read_field(&layout.fields[i], &f);
        where->field = i;
        where->element = element;
        if (f.kind <= WIRE_ENUM8) {
            wire_value_t v = scalar_load(f.kind, msg + f.offset);
            if (!scalar_ok(f.kind, &f.range, v))
                return WIRE_FIELD_RANGE;
            uint8_t size = scalar_size(f.kind);
            if ((uint32_t)*pos + size > cap)
                return WIRE_LENGTH;
            scalar_write(f.kind, out + *pos, v);
            *pos += size;
            continue;
        }
        uint8_t n = msg[f.offset];
        if (f.kind == WIRE_TEXT || f.kind == WIRE_BLOB) {
            if (n > f.max_count || (f.kind == WIRE_TEXT && !wire_utf8_valid(msg + f.data_offset, n)))
                return WIRE_FIELD_RANGE;
            if ((uint32_t)*pos + 1u + n > cap)
                return WIRE_LENGTH;
            out[(*pos)++] = n;
            memcpy(out + *pos, msg + f.data_offset, n);
            *pos += n;
            continue;
        }
        if (n < f.min_count || n > f.max_count)
            return WIRE_FIELD_RANGE;
        if (*pos >= cap)
            return WIRE_LENGTH;
        out[(*pos)++] = n;
        for (uint8_t k = 0; k < n; k++) {
            const uint8_t *item = msg + f.data_offset + (uint16_t)k * f.elem_size;
            if (f.elem == WIRE_RECORD) {
                wire_where_t inner;
                wire_status_t st = encode_layout(&wire_records[f.record], item, out, cap, pos, &inner, k);
                if (st != WIRE_OK) {
                    where->element = k;
                    return st;
                }
                continue;
            }
            wire_value_t v = scalar_load(f.elem, item);
            if (!scalar_ok(f.elem, &f.range, v)) {
                where->element = k;
                return WIRE_FIELD_RANGE;
            }
            uint8_t size = scalar_size(f.elem);
            if ((uint32_t)*pos + size > cap) {
                where->element = k;
                return WIRE_LENGTH;
            }
            scalar_write(f.elem, out + *pos, v);
            *pos += size;
        }
    }
    return WIRE_OK;
}

wire_status_t wire_encode(const wire_layout_t *layout, const void *msg, uint8_t *out, uint16_t cap,
                          uint16_t *len, wire_where_t *where)
{
    wire_where_t ignored;
    if (!where)
        where = &ignored;
    where->field = 0;
    where->element = 0xFF;
    uint16_t pos = 0;
    wire_status_t st = encode_layout(layout, (const uint8_t *)msg, out, cap, &pos, where, 0xFF);
    *len = pos;
    return st;
}
