/* crc16.c - CRC-16/CCITT-FALSE, a byte at a time without a table (512 bytes of flash saved).
 *
 * The polynomial 0x1021 = x^16 + x^12 + x^5 + 1 has so few terms that a byte's eight shift-and-xor steps
 * fold into three shifts of one value: with x the byte xored into the CRC's high byte, and x ^= x >> 4
 * (the bits of x that feed back within the byte), the new CRC is (crc << 8) ^ (x << 12) ^ (x << 5) ^ x.
 * About 30 AVR cycles a byte where the bitwise loop took ~160: every frame in and out is checksummed,
 * and with the line busy both ways the bitwise loop was the main loop's largest cost (28 % of it while a
 * host uploaded calibrations during a download, and the receive ring overflowed:
 * tests/test_firmware_rx_keeps_up.py). */
#include "crc16.h"

uint16_t crc16_update(uint16_t crc, const uint8_t *data, uint16_t len)
{
    while (len--) {
        uint8_t x = (uint8_t)((crc >> 8) ^ *data++);
        x ^= (uint8_t)(x >> 4);
        crc = (uint16_t)((crc << 8) ^ ((uint16_t)x << 12) ^ ((uint16_t)x << 5) ^ x);
    }
    return crc;
}
