/* cobs.c - COBS encode/decode (see cobs.h). */
#include "cobs.h"

uint16_t cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out)
{
    uint16_t code_at = 0; /* where the current group's code byte goes */
    uint16_t o = 1;
    uint8_t code = 1;
    for (uint16_t i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
            continue;
        }
        out[o++] = in[i];
        if (++code == 0xFF) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        }
    }
    out[code_at] = code;
    return o;
}

int16_t cobs_decode_in_place(uint8_t *buf, uint16_t len)
{
    uint16_t i = 0, o = 0;
    while (i < len) {
        uint8_t code = buf[i];
        if (code == 0)
            return -1;
        uint16_t end = (uint16_t)(i + code);
        if (end > len)
            return -1;
        for (uint16_t k = (uint16_t)(i + 1); k < end; k++) {
            if (buf[k] == 0)
                return -1;
            buf[o++] = buf[k];
        }
        i = end;
        if (code != 0xFF && i < len)
            buf[o++] = 0;
    }
    return (int16_t)o;
}
