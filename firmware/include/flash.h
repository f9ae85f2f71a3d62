/* flash.h - constant tables in program memory on the AVR (8 KB of RAM is precious), plain memory on the
 * host, behind one set of names so the portable modules compile for both. */
#ifndef FLASH_H
#define FLASH_H

#include <string.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define FLASH PROGMEM
#define flash_read(dst, src, n) memcpy_P((dst), (src), (n))
#define flash_byte(p) pgm_read_byte(p)
#else
#define FLASH
#define flash_read(dst, src, n) memcpy((dst), (src), (n))
#define flash_byte(p) (*(const unsigned char *)(p))
#endif

/* Copy the `index`-th of the NUL-separated strings in `table` (in flash) into `out` (room for `n`). */
static inline void flash_pick(const char *table, unsigned index, char *out, unsigned n)
{
    while (index--)
        while (flash_byte(table++))
            ;
    unsigned i = 0;
    for (char c; n && i < n - 1 && (c = (char)flash_byte(table + i)); i++)
        out[i] = c;
    if (n)
        out[i] = 0;
}

#endif /* FLASH_H */
