/* cobs.h - Consistent Overhead Byte Stuffing, the canonical form of protocol/cobs.py.
 *
 * The encoder writes a block of 254 non-zero bytes as 0xFF + 254 bytes and always closes the input with a
 * group (so an input ending in a 254-byte run ends with an extra 0x01); the decoder accepts either form. */
#ifndef COBS_H
#define COBS_H

#include <stdint.h>

/* Upper bound on the encoded length of n bytes (without the delimiter). */
#define COBS_MAX_ENCODED(n) ((n) + (n) / 254u + 1u)

/* Encode `len` bytes into `out` (room for COBS_MAX_ENCODED(len)); returns the encoded length. */
uint16_t cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out);

/* Decode `len` bytes in place (the output is never longer). Returns the decoded length, or -1 if a group
 * runs past the end or a zero byte appears inside (reason COBS). */
int16_t cobs_decode_in_place(uint8_t *buf, uint16_t len);

#endif /* COBS_H */
