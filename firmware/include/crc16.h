/* crc16.h - CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection; check("123456789") = 0x29B1).
 * The same checksum as protocol/crc.py; pass the previous result as `crc` to checksum in pieces. */
#ifndef CRC16_H
#define CRC16_H

#include <stdint.h>

#define CRC16_INIT 0xFFFFu

uint16_t crc16_update(uint16_t crc, const uint8_t *data, uint16_t len);

#endif /* CRC16_H */
