/* max3421e.c - the MAX3421E driver, register level (see max3421e_drv.h). Portable. */
#include "max3421e_drv.h"

#include "spi.h"

static void command(uint8_t reg, uint8_t write)
{
    spi_select(1);
    spi_byte((uint8_t)(reg << 3 | (write ? 0x02u : 0u))); /* MISO: HIRQ (full duplex), not needed here */
}

uint8_t max_read(uint8_t reg)
{
    command(reg, 0);
    uint8_t v = spi_byte(0);
    spi_select(0);
    return v;
}

void max_write(uint8_t reg, uint8_t value)
{
    command(reg, 1);
    spi_byte(value);
    spi_select(0);
}

void max_read_fifo(uint8_t reg, uint8_t *dst, uint8_t n)
{
    command(reg, 0);
    while (n--)
        *dst++ = spi_byte(0);
    spi_select(0);
}

void max_write_fifo(uint8_t reg, const uint8_t *src, uint8_t n)
{
    command(reg, 1);
    while (n--)
        spi_byte(*src++);
    spi_select(0);
}

void max_chip_reset(void)
{
    /* full duplex first: every later read relies on MISO; INT in level mode, GPX as "operate" */
    max_write(MAX_PINCTL, MAX_FDUPSPI | MAX_INTLEVEL);
    max_write(MAX_USBCTL, MAX_CHIPRES);
    max_write(MAX_USBCTL, 0);
}

uint8_t max_osc_ok(void) { return (max_read(MAX_USBIRQ) & MAX_OSCOKIRQ) != 0; }

void max_host_mode(void)
{
    max_write(MAX_MODE, MAX_DPPULLDN | MAX_DMPULLDN | MAX_HOST);
    max_write(MAX_HIEN, MAX_CONDETIRQ);
    max_write(MAX_HIRQ, MAX_CONDETIRQ); /* forget a connect event from before host mode */
    max_write(MAX_CPUCTL, MAX_IE);
}

max_bus_t max_sample_bus(void)
{
    max_write(MAX_HCTL, MAX_SAMPLEBUS);
    uint32_t t0 = usb_now_us();
    /* the chip clears SAMPLEBUS when the sample is taken (a few bit times); bounded in case it never does */
    while ((max_read(MAX_HCTL) & MAX_SAMPLEBUS) && usb_now_us() - t0 < 100u)
        ;
    uint8_t jk = max_read(MAX_HRSL) & (MAX_JSTATUS | MAX_KSTATUS);
    if (jk == MAX_JSTATUS)
        return MAX_BUS_FULL;
    if (jk == MAX_KSTATUS)
        return MAX_BUS_LOW;
    return jk ? MAX_BUS_SE1 : MAX_BUS_SE0;
}

void max_set_speed(max_bus_t bus)
{
    uint8_t mode = MAX_DPPULLDN | MAX_DMPULLDN | MAX_HOST | MAX_SOFKAENAB;
    if (bus == MAX_BUS_LOW)
        mode |= MAX_LOWSPEED;
    max_write(MAX_MODE, mode);
}

void max_bus_reset(void)
{
    max_write(MAX_MODE, MAX_DPPULLDN | MAX_DMPULLDN | MAX_HOST); /* no SOFs during the reset */
    max_write(MAX_HCTL, MAX_BUSRST);
}

uint8_t max_bus_reset_done(void) { return !(max_read(MAX_HCTL) & MAX_BUSRST); }

uint8_t max_xfer(uint8_t token_ep)
{
    max_write(MAX_HIRQ, MAX_HXFRDNIRQ); /* a stale "done" must not end this wait */
    max_write(MAX_HXFR, token_ep);
    uint32_t t0 = usb_now_us();
    for (;;) {
        uint8_t hirq = max_read(MAX_HIRQ);
        if (hirq & MAX_HXFRDNIRQ)
            break;
        if (usb_now_us() - t0 >= MAX_XFER_WAIT_US)
            return MAX_HR_NO_ANSWER;
    }
    max_write(MAX_HIRQ, MAX_HXFRDNIRQ);
    return max_read(MAX_HRSL) & 0x0Fu;
}
