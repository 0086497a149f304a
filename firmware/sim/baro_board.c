/*
 * baro_board: the barometer board in simavr, for firmware-in-the-loop tests.
 *
 * Loads the firmware ELF into a simulated ATmega328P at 16 MHz, attaches a virtual Bosch
 * BMP280 to the TWI pins and bridges UART0 to a pseudo-terminal, so a host program (the Python
 * codec, the daemon) talks to the real firmware exactly as it would to a board on USB.
 *
 * The virtual BMP280 has the real register map: calibration words at 0x88..0x9F, chip id 0x58
 * at 0xD0, soft reset at 0xE0, status at 0xF3, ctrl_meas/config at 0xF4/0xF5 and the 20-bit
 * pressure and temperature at 0xF7..0xFC. In normal mode it completes a measurement every
 * t_measure (from the oversampling, data sheet's typical timing) + t_standby; each measurement
 * puts in the data registers the ADC values that Bosch's integer compensation turns back into
 * the pressure and temperature the trajectory gives at that moment: the harness inverts the
 * formula by bisection on the ADC value. A burst read is served from a snapshot taken at the
 * start of the read, as the real chip's shadow registers do. The IIR filter is not modelled
 * (its setting is stored and read back): the data are the unfiltered trajectory, so a test can
 * compare what the board reports with what was injected.
 *
 * With --sensor ms5611 the virtual device is a TE MS5611 instead: commands reset (0x1E), PROM
 * read (0xA0..0xAE, with a valid CRC-4), D1/D2 conversions (0x40.., 0x50.., OSR 256..4096 with
 * the data sheet's maximum conversion times) and ADC read (0x00; 0 when read before the
 * conversion ended). The raw values are again found by bisection so that the data sheet's
 * compensation (second order included) gives the trajectory's values at the end of each
 * conversion; the truth log then has one line per D1 read (adc_p = D1, adc_t = the last D2).
 *
 * Trajectory file (--trajectory): CSV lines "time_s,pressure_pa,temperature_c,present" (a
 * header line is skipped), time in simulated seconds since the simulation started. Pressure
 * and temperature are interpolated linearly; `present` (0/1) holds from its row on: while 0,
 * the sensor does not answer on the bus; when it returns it has been power-cycled (sleep mode,
 * no data, registers at their reset values).
 *
 * Truth log (--truth): one CSV line per burst read of the data registers:
 *   read_us,meas_us,pressure_pa,temperature_c,adc_p,adc_t
 * (meas_us -1 when no measurement has completed yet).
 *
 * Output: the line "baro_board: pty <path>" on stdout once the pseudo-terminal exists; after
 * it stdout is redirected to stderr (simavr prints there). A summary goes to stderr at exit.
 * SIGINT/SIGTERM end the simulation cleanly.
 *
 * usage: baro_board FIRMWARE.elf [--trajectory CSV] [--truth CSV] [--speed X] [--address 0x76]
 *                   [--sensor bmp280|ms5611] [--wait-host] [--duration S] [--no-backpressure]
 *   --speed X        simulated seconds per wall second (default 1.0); 0 = as fast as possible
 *   --wait-host      start the AVR only once a program has opened the pty (as a real board
 *                    resets when the port opens), so its first frames are not lost
 *   --duration S     stop after S simulated seconds
 *   backpressure     by default the simulation pauses while the host has not read 8 KiB of
 *                    output (a real board would lose it), so a busy test machine cannot make
 *                    the firmware look lossy; --no-backpressure drops instead.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_twi.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_irq.h>
#include <sim_time.h>

#define F_CPU_HZ 16000000u
#define OUT_CAP (1u << 20)
#define IN_CAP (1u << 16)
#define BACKPRESSURE_HIGH 8192u
#define SERVICE_PERIOD_US 500u
#define UART_BYTE_US 100u

static volatile sig_atomic_t stop_requested = 0;

static void on_signal(int sig) {
	(void)sig;
	stop_requested = 1;
}

static double wall_now(void) {
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* ---------------------------------------------------------------- trajectory -- */

typedef struct {
	double t, p, temp;
	int present;
} traj_row_t;

static traj_row_t *traj = NULL;
static size_t traj_len = 0;

static int load_trajectory(const char *path) {
	FILE *f = fopen(path, "r");
	if (!f) {
		perror(path);
		return -1;
	}
	char line[256];
	size_t cap = 0;
	while (fgets(line, sizeof line, f)) {
		traj_row_t row;
		if (sscanf(line, "%lf,%lf,%lf,%d", &row.t, &row.p, &row.temp, &row.present) != 4)
			continue; /* header or blank */
		if (traj_len == cap) {
			cap = cap ? 2 * cap : 256;
			traj = realloc(traj, cap * sizeof *traj);
			if (!traj) {
				fclose(f);
				return -1;
			}
		}
		traj[traj_len++] = row;
	}
	fclose(f);
	if (traj_len == 0) {
		fprintf(stderr, "baro_board: %s has no rows\n", path);
		return -1;
	}
	return 0;
}

/* Pressure and temperature at simulated time t (s), and whether the sensor is attached. */
static void trajectory_at(double t, double *p, double *temp, int *present) {
	if (traj_len == 0) {
		*p = 101325.0;
		*temp = 22.0;
		*present = 1;
		return;
	}
	if (t <= traj[0].t) {
		*p = traj[0].p;
		*temp = traj[0].temp;
		*present = traj[0].present;
		return;
	}
	size_t lo = 0, hi = traj_len - 1;
	if (t >= traj[hi].t) {
		*p = traj[hi].p;
		*temp = traj[hi].temp;
		*present = traj[hi].present;
		return;
	}
	while (hi - lo > 1) { /* traj[lo].t <= t < traj[hi].t */
		size_t mid = (lo + hi) / 2;
		if (traj[mid].t <= t)
			lo = mid;
		else
			hi = mid;
	}
	double span = traj[hi].t - traj[lo].t;
	double w = span > 0 ? (t - traj[lo].t) / span : 0.0;
	*p = traj[lo].p + w * (traj[hi].p - traj[lo].p);
	*temp = traj[lo].temp + w * (traj[hi].temp - traj[lo].temp);
	*present = traj[lo].present;
}

/* ------------------------------------------------- BMP280 compensation (data sheet) -- */

typedef struct {
	uint16_t T1;
	int16_t T2, T3;
	uint16_t P1;
	int16_t P2, P3, P4, P5, P6, P7, P8, P9;
} calib_t;

/* A plausible part's trimming, deliberately not the data sheet example the unit tests use. */
static const calib_t CALIB = {28347, 26370, 50, 36372, -10539, 3024, 7003, -52, -7, 15500, -14600, 6000};

static int32_t comp_t_fine(int32_t adc_t) {
	/* right shifts of negative values are arithmetic (floor) with gcc, as the data sheet means */
	int32_t a = (((adc_t >> 3) - (int32_t)CALIB.T1 * 2) * (int32_t)CALIB.T2) >> 11;
	int32_t d = (adc_t >> 4) - (int32_t)CALIB.T1;
	int32_t b = (((d * d) >> 12) * (int32_t)CALIB.T3) >> 14;
	return a + b;
}

static int64_t comp_p_q24_8(int32_t t_fine, int32_t adc_p) {
	int64_t v1 = (int64_t)t_fine - 128000;
	int64_t v2 = v1 * v1 * CALIB.P6 + v1 * CALIB.P5 * 131072 + (int64_t)CALIB.P4 * 34359738368LL;
	v1 = ((v1 * v1 * CALIB.P3) >> 8) + v1 * CALIB.P2 * 4096;
	v1 = ((140737488355328LL + v1) * CALIB.P1) >> 33;
	if (v1 == 0)
		return 0;
	int64_t p = 1048576 - (int64_t)adc_p;
	p = ((p * 2147483648LL - v2) * 3125) / v1;
	int64_t a = ((int64_t)CALIB.P9 * (p >> 13) * (p >> 13)) >> 25;
	int64_t b = ((int64_t)CALIB.P8 * p) >> 19;
	return ((p + a + b) >> 8) + (int64_t)CALIB.P7 * 16;
}

/* ADC values whose compensation gives temp (degC) and p (Pa) as closely as 20 bits allow. */
static void invert(double p_pa, double temp_c, int32_t *adc_p, int32_t *adc_t) {
	/* t_fine grows with adc_T (T2 > 0): smallest adc with t_fine >= target, or its neighbour */
	double want_tf = temp_c * 5120.0;
	int32_t lo = 0, hi = (1 << 20) - 1;
	while (lo < hi) {
		int32_t mid = lo + (hi - lo) / 2;
		if (comp_t_fine(mid) >= want_tf)
			hi = mid;
		else
			lo = mid + 1;
	}
	if (lo > 0 && fabs(comp_t_fine(lo - 1) - want_tf) < fabs(comp_t_fine(lo) - want_tf))
		lo--;
	*adc_t = lo;
	int32_t t_fine = comp_t_fine(lo);
	/* pressure falls as adc_P grows: smallest adc with p <= target, or its neighbour */
	double want = p_pa * 256.0;
	lo = 0;
	hi = (1 << 20) - 1;
	while (lo < hi) {
		int32_t mid = lo + (hi - lo) / 2;
		if (comp_p_q24_8(t_fine, mid) <= want)
			hi = mid;
		else
			lo = mid + 1;
	}
	if (lo > 0 && fabs(comp_p_q24_8(t_fine, lo - 1) - want) < fabs(comp_p_q24_8(t_fine, lo) - want))
		lo--;
	*adc_p = lo;
}

/* ------------------------------------------------------------------ virtual BMP280 -- */

enum { REG_CALIB = 0x88, REG_ID = 0xD0, REG_RESET = 0xE0, REG_STATUS = 0xF3, REG_CTRL = 0xF4,
       REG_CONFIG = 0xF5, REG_DATA = 0xF7 };

/* What both virtual sensors share on the bus: their address, whether the trajectory has them
 * present, whether the current transaction addressed them, and what the summary counts. */
typedef struct {
	avr_t *avr;
	avr_irq_t *irq; /* [0] to the AVR's TWI input, [1] from its output */
	uint8_t addr7;
	int selected, present;
	FILE *truth;
	unsigned long transactions, nacked, data_reads;
} twi_dev_t;

static void twi_dev_attach(twi_dev_t *d, avr_t *avr, uint8_t addr7, const char *names[2],
                           avr_irq_notify_t hook, void *param) {
	d->avr = avr;
	d->addr7 = addr7;
	d->irq = avr_alloc_irq(&avr->irq_pool, 0, 2, names);
	avr_irq_register_notify(d->irq + 1, hook, param);
	avr_connect_irq(d->irq + 0, avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT));
	avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), d->irq + 1);
	double p, temp;
	trajectory_at(0, &p, &temp, &d->present);
}

/* A START with an address: 1 if it is this device's and the device is there (selected now; the
 * caller answers ACK), 0 if not addressed or absent (no ACK: the master sees an address NACK).
 * *appeared says the device has just come back, so it powers up. */
static int twi_dev_start(twi_dev_t *d, uint8_t addr, double now, int *appeared) {
	d->selected = 0;
	*appeared = 0;
	if ((addr >> 1) != d->addr7)
		return 0;
	double p, temp;
	int present;
	trajectory_at(now * 1e-6, &p, &temp, &present);
	*appeared = present && !d->present;
	d->present = present;
	d->transactions++;
	if (!present) {
		d->nacked++;
		return 0;
	}
	d->selected = 1;
	return 1;
}

typedef struct {
	twi_dev_t dev;
	uint8_t regs[256];
	uint8_t data[6];     /* latest measurement: press msb lsb xlsb, temp msb lsb xlsb */
	uint8_t snapshot[6]; /* what the current burst read returns */
	uint8_t ptr;
	int index;
	double nvm_busy_until;   /* us */
	double normal_since;     /* us, start of normal mode; < 0 when sleeping */
	long meas_index;         /* index of the measurement in data[], -1 none */
	double meas_time;        /* us */
	double meas_p, meas_temp;
	int32_t meas_adc_p, meas_adc_t;
} vbmp_t;

static vbmp_t bmp;

static double sim_us(avr_t *avr) { return avr->cycle * (1e6 / F_CPU_HZ); }

static void bmp_power_on(vbmp_t *b, double now) {
	memset(b->regs, 0, sizeof b->regs);
	const calib_t *c = &CALIB;
	uint16_t words[12] = {c->T1, (uint16_t)c->T2, (uint16_t)c->T3, c->P1, (uint16_t)c->P2,
	                      (uint16_t)c->P3, (uint16_t)c->P4, (uint16_t)c->P5, (uint16_t)c->P6,
	                      (uint16_t)c->P7, (uint16_t)c->P8, (uint16_t)c->P9};
	for (int i = 0; i < 12; i++) {
		b->regs[REG_CALIB + 2 * i] = words[i] & 0xFF;
		b->regs[REG_CALIB + 2 * i + 1] = words[i] >> 8;
	}
	b->regs[REG_ID] = 0x58;
	const uint8_t skipped[6] = {0x80, 0x00, 0x00, 0x80, 0x00, 0x00};
	memcpy(b->data, skipped, 6);
	b->nvm_busy_until = now + 1000.0;
	b->normal_since = -1.0;
	b->meas_index = -1;
}

static double osrs_factor(uint8_t code) { /* register code -> oversampling; 0 = skipped */
	static const double f[8] = {0, 1, 2, 4, 8, 16, 16, 16};
	return f[code & 7];
}

static double measure_us(const vbmp_t *b) {
	uint8_t ctrl = b->regs[REG_CTRL];
	double t_os = osrs_factor(ctrl >> 5), p_os = osrs_factor((ctrl >> 2) & 7);
	double ms = 1.0 + (t_os ? 2.0 * t_os : 0) + (p_os ? 2.0 * p_os + 0.5 : 0);
	return ms * 1000.0;
}

static double standby_us(const vbmp_t *b) {
	static const double sb[8] = {500, 62500, 125000, 250000, 500000, 1000000, 2000000, 4000000};
	return sb[b->regs[REG_CONFIG] >> 5];
}

/* Bring data[] up to the latest measurement completed by `now`. */
static void bmp_update(vbmp_t *b, double now) {
	if (b->normal_since < 0)
		return;
	double t_meas = measure_us(b), period = t_meas + standby_us(b);
	double first_end = b->normal_since + t_meas;
	if (now < first_end)
		return;
	long k = (long)floor((now - first_end) / period);
	if (k == b->meas_index)
		return;
	double end = first_end + k * period;
	double p, temp;
	int present;
	trajectory_at(end * 1e-6, &p, &temp, &present);
	int32_t adc_p, adc_t;
	invert(p, temp, &adc_p, &adc_t);
	uint8_t ctrl = b->regs[REG_CTRL];
	if ((ctrl >> 2) & 7) {
		b->data[0] = adc_p >> 12;
		b->data[1] = (adc_p >> 4) & 0xFF;
		b->data[2] = (adc_p & 0x0F) << 4;
	}
	if (ctrl >> 5) {
		b->data[3] = adc_t >> 12;
		b->data[4] = (adc_t >> 4) & 0xFF;
		b->data[5] = (adc_t & 0x0F) << 4;
	}
	b->meas_index = k;
	b->meas_time = end;
	b->meas_p = p;
	b->meas_temp = temp;
	b->meas_adc_p = adc_p;
	b->meas_adc_t = adc_t;
}

static uint8_t bmp_read(vbmp_t *b, uint8_t reg, double now) {
	if (reg >= REG_DATA && reg < REG_DATA + 6)
		return b->snapshot[reg - REG_DATA];
	if (reg == REG_STATUS) {
		uint8_t s = now < b->nvm_busy_until ? 0x01 : 0x00;
		if (b->normal_since >= 0) {
			double t_meas = measure_us(b), period = t_meas + standby_us(b);
			if (fmod(now - b->normal_since, period) < t_meas)
				s |= 0x08;
		}
		return s;
	}
	return b->regs[reg];
}

static void bmp_write(vbmp_t *b, uint8_t reg, uint8_t v, double now) {
	switch (reg) {
	case REG_RESET:
		if (v == 0xB6)
			bmp_power_on(b, now);
		break;
	case REG_CTRL:
		bmp_update(b, now);
		b->regs[REG_CTRL] = v;
		/* normal mode restarts its cycle; sleep stops it (forced mode is not modelled) */
		b->normal_since = (v & 3) == 3 ? now : -1.0;
		b->meas_index = -1;
		break;
	case REG_CONFIG:
		b->regs[REG_CONFIG] = v & 0xFD;
		break;
	default:
		break; /* read-only */
	}
}

static void twi_reply(avr_irq_t *irq, uint8_t msg, uint8_t addr, uint8_t data) {
	avr_raise_irq(irq + 0, avr_twi_irq_msg(msg, addr, data));
}

/* Messages from the AVR's TWI master: START (+address), WRITE, READ, STOP. */
static void bmp_twi_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	vbmp_t *b = param;
	avr_twi_msg_irq_t v;
	v.u.v = value;
	double now = sim_us(b->dev.avr);
	if (v.u.twi.msg & TWI_COND_STOP)
		b->dev.selected = 0;
	if (v.u.twi.msg & TWI_COND_START) {
		b->index = 0;
		int appeared;
		if (!twi_dev_start(&b->dev, v.u.twi.addr, now, &appeared))
			return;
		if (appeared)
			bmp_power_on(b, now);
		if (v.u.twi.addr & 1) { /* read: serve from a snapshot, like the shadow registers */
			bmp_update(b, now);
			memcpy(b->snapshot, b->data, 6);
			if (b->ptr == REG_DATA) {
				b->dev.data_reads++;
				if (b->dev.truth) {
					if (b->meas_index >= 0)
						fprintf(b->dev.truth, "%.1f,%.1f,%.6f,%.4f,%d,%d\n", now, b->meas_time,
						        b->meas_p, b->meas_temp, b->meas_adc_p, b->meas_adc_t);
					else
						fprintf(b->dev.truth, "%.1f,-1,nan,nan,%d,%d\n", now, 0x80000, 0x80000);
				}
			}
		}
		twi_reply(b->dev.irq, TWI_COND_ACK, v.u.twi.addr, 1);
		return;
	}
	if (!b->dev.selected)
		return;
	if (v.u.twi.msg & TWI_COND_WRITE) {
		twi_reply(b->dev.irq, TWI_COND_ACK, v.u.twi.addr, 1);
		/* writes come as register, value, register, value... */
		if (b->index % 2 == 0)
			b->ptr = v.u.twi.data;
		else
			bmp_write(b, b->ptr, v.u.twi.data, now);
		b->index++;
	}
	if (v.u.twi.msg & TWI_COND_READ) {
		uint8_t data = bmp_read(b, b->ptr, now);
		b->ptr++;
		twi_reply(b->dev.irq, TWI_COND_READ, v.u.twi.addr, data);
	}
}

static void bmp_attach(avr_t *avr, vbmp_t *b, uint8_t addr7) {
	static const char *names[2] = {"8>bmp280.out", "32<bmp280.in"};
	memset(b, 0, sizeof *b);
	twi_dev_attach(&b->dev, avr, addr7, names, bmp_twi_hook, b);
	bmp_power_on(b, 0);
}

/* ------------------------------------------------------------------ virtual MS5611 -- */

/* Data sheet typical coefficients C1..C6, a factory word C0; C7 gets its CRC-4 at start-up. */
static uint16_t ms_prom[8] = {0x0045, 40127, 36924, 23317, 23282, 33464, 28312, 0x0000};

static uint8_t ms_crc4(const uint16_t *prom) { /* AN520 */
	uint16_t rem = 0;
	for (int i = 0; i < 16; i++) {
		uint16_t w = prom[i >> 1];
		if (i >= 14)
			w &= 0xFF00;
		rem ^= (i & 1) ? (w & 0xFF) : (w >> 8);
		for (int b = 0; b < 8; b++)
			rem = (rem & 0x8000) ? (uint16_t)((rem << 1) ^ 0x3000) : (uint16_t)(rem << 1);
	}
	return (rem >> 12) & 0x0F;
}

/* The data sheet's compensation, written again here so the test compares two implementations. */
static void ms_comp(uint32_t d1, uint32_t d2, int64_t *temp_centi, int64_t *p_q8) {
	const uint16_t *c = ms_prom;
	int64_t dt = (int64_t)d2 - ((int64_t)c[5] << 8);
	int64_t temp = 2000 + dt * c[6] / 8388608;
	int64_t off = (int64_t)c[2] * 65536 + (int64_t)c[4] * dt / 128;
	int64_t sens = (int64_t)c[1] * 32768 + (int64_t)c[3] * dt / 256;
	if (temp < 2000) {
		int64_t t2 = dt * dt / 2147483648LL, cold = (temp - 2000) * (temp - 2000);
		int64_t off2 = 5 * cold / 2, sens2 = 5 * cold / 4;
		if (temp < -1500) {
			off2 += 7 * (temp + 1500) * (temp + 1500);
			sens2 += 11 * (temp + 1500) * (temp + 1500) / 2;
		}
		temp -= t2;
		off -= off2;
		sens -= sens2;
	}
	*temp_centi = temp;
	*p_q8 = ((int64_t)d1 * sens / 2097152 - off) / 128;
}

/* TEMP (0.01 degC) as a continuous function of D2: the integer formula rounds to 0.01 degC,
 * but OFF and SENS use dT itself, so D2 must follow the temperature smoothly (one LSB is about
 * 0.00003 degC) or a pressure sample would jump by up to 2 Pa whenever TEMP steps. */
static double ms_temp_exact(uint32_t d2) {
	double dt = (double)d2 - ms_prom[5] * 256.0;
	double temp = 2000.0 + dt * ms_prom[6] / 8388608.0;
	return temp < 2000.0 ? temp - dt * dt / 2147483648.0 : temp;
}

/* D2 for temp_c, then the D1 whose compensation with that D2 comes closest to p_pa. */
static void ms_invert(double p_pa, double temp_c, uint32_t *d1, uint32_t *d2) {
	int64_t t, p, p_lo;
	uint32_t lo = 0, hi = (1u << 24) - 1; /* TEMP grows with D2 */
	while (lo < hi) {
		uint32_t mid = lo + (hi - lo) / 2;
		if (ms_temp_exact(mid) >= temp_c * 100.0)
			hi = mid;
		else
			lo = mid + 1;
	}
	*d2 = lo;
	lo = 0;
	hi = (1u << 24) - 1; /* P grows with D1 */
	while (lo < hi) {
		uint32_t mid = lo + (hi - lo) / 2;
		ms_comp(mid, *d2, &t, &p);
		if (p >= p_pa * 256.0)
			hi = mid;
		else
			lo = mid + 1;
	}
	if (lo > 0) {
		ms_comp(lo, *d2, &t, &p);
		ms_comp(lo - 1, *d2, &t, &p_lo);
		if (fabs(p_lo - p_pa * 256.0) < fabs(p - p_pa * 256.0))
			lo--;
	}
	*d1 = lo;
}

typedef struct {
	twi_dev_t dev;
	uint8_t command; /* last command byte written */
	int conv_kind;   /* conversion under way: 1 = D1, 2 = D2, 0 = none */
	double conv_end; /* us */
	uint32_t adc;    /* result of the finished conversion, served by ADC read */
	int adc_valid;
	uint8_t out[3]; /* bytes of the current read */
	int out_index;
	uint32_t last_d2;
} vms_t;

static vms_t ms;

static void ms_finish_conversion(vms_t *m) {
	double p, temp;
	int present;
	trajectory_at(m->conv_end * 1e-6, &p, &temp, &present);
	uint32_t d1, d2;
	ms_invert(p, temp, &d1, &d2);
	m->adc = m->conv_kind == 1 ? d1 : d2;
	m->adc_valid = 1;
	if (m->conv_kind == 2)
		m->last_d2 = d2;
	if (m->conv_kind == 1 && m->dev.truth)
		fprintf(m->dev.truth, "%.1f,%.1f,%.6f,%.4f,%u,%u\n", sim_us(m->dev.avr), m->conv_end, p,
		        temp, d1, m->last_d2);
	m->conv_kind = 0;
}

static void ms_twi_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	vms_t *m = param;
	avr_twi_msg_irq_t v;
	v.u.v = value;
	double now = sim_us(m->dev.avr);
	if (v.u.twi.msg & TWI_COND_STOP)
		m->dev.selected = 0;
	if (v.u.twi.msg & TWI_COND_START) {
		int appeared;
		if (!twi_dev_start(&m->dev, v.u.twi.addr, now, &appeared))
			return;
		if (appeared) { /* power-up: nothing converted */
			m->conv_kind = 0;
			m->adc_valid = 0;
		}
		if (v.u.twi.addr & 1) { /* read: what the last command asked for */
			m->out_index = 0;
			memset(m->out, 0, sizeof m->out);
			if (m->command == 0x00) {
				if (m->conv_kind && now >= m->conv_end)
					ms_finish_conversion(m);
				if (m->adc_valid) {
					m->out[0] = m->adc >> 16;
					m->out[1] = m->adc >> 8;
					m->out[2] = m->adc;
				}
				m->adc_valid = 0; /* a second read gives 0, as on the chip */
				m->dev.data_reads++;
			} else if (m->command >= 0xA0 && m->command <= 0xAE) {
				uint16_t w = ms_prom[(m->command - 0xA0) / 2];
				m->out[0] = w >> 8;
				m->out[1] = w & 0xFF;
			}
		}
		twi_reply(m->dev.irq, TWI_COND_ACK, v.u.twi.addr, 1);
		return;
	}
	if (!m->dev.selected)
		return;
	if (v.u.twi.msg & TWI_COND_WRITE) {
		twi_reply(m->dev.irq, TWI_COND_ACK, v.u.twi.addr, 1);
		uint8_t cmd = v.u.twi.data;
		m->command = cmd;
		if (cmd == 0x1E) {
			m->conv_kind = 0;
			m->adc_valid = 0;
		} else if ((cmd & 0xF0) == 0x40 || (cmd & 0xF0) == 0x50) {
			static const double conv_us[5] = {600, 1170, 2280, 4540, 9040};
			int osr = ((cmd & 0x0F) >> 1) % 5;
			m->conv_kind = (cmd & 0xF0) == 0x40 ? 1 : 2;
			m->conv_end = now + conv_us[osr];
			m->adc_valid = 0;
		}
	}
	if (v.u.twi.msg & TWI_COND_READ) {
		uint8_t data = m->out_index < 3 ? m->out[m->out_index] : 0;
		m->out_index++;
		twi_reply(m->dev.irq, TWI_COND_READ, v.u.twi.addr, data);
	}
}

static void ms_attach(avr_t *avr, vms_t *m, uint8_t addr7) {
	static const char *names[2] = {"8>ms5611.out", "32<ms5611.in"};
	memset(m, 0, sizeof *m);
	m->command = 0xFF;
	ms_prom[7] = (ms_prom[7] & 0xFFF0) | ms_crc4(ms_prom);
	twi_dev_attach(&m->dev, avr, addr7, names, ms_twi_hook, m);
}

/* --------------------------------------------------------------- UART <-> pty -- */

static int pty_master = -1;
static uint8_t *out_buf; /* board -> host */
static size_t out_len = 0;
static uint8_t *in_buf; /* host -> board */
static size_t in_head = 0, in_len = 0;
static int uart_xoff = 0;
static int backpressure = 1;
static unsigned long bytes_to_host = 0, bytes_from_host = 0, bytes_dropped = 0;
static avr_irq_t *uart_in_irq;

static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)param;
	if (out_len < OUT_CAP)
		out_buf[out_len++] = (uint8_t)value;
	else
		bytes_dropped++;
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)value;
	(void)param;
	uart_xoff = 0;
}

static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq;
	(void)param;
	uart_xoff = value != 0;
}

/* One host byte per UART_BYTE_US of simulated time: the wire's pace, not the host's. */
static avr_cycle_count_t uart_feed_timer(avr_t *avr, avr_cycle_count_t when, void *param) {
	(void)param;
	if (in_len > 0 && !uart_xoff) {
		uint8_t byte = in_buf[in_head];
		in_head = (in_head + 1) % IN_CAP;
		in_len--;
		avr_raise_irq(uart_in_irq, byte);
	}
	return when + avr_usec_to_cycles(avr, UART_BYTE_US);
}

static int host_connected(void) {
	struct pollfd pfd = {.fd = pty_master, .events = POLLIN};
	if (poll(&pfd, 1, 0) < 0)
		return 0;
	return !(pfd.revents & POLLHUP);
}

/* Move bytes between the pty and the buffers without blocking. */
static void service_pty(void) {
	int connected = host_connected();
	while (connected && in_len < IN_CAP) {
		uint8_t chunk[512];
		size_t room = IN_CAP - in_len;
		ssize_t n = read(pty_master, chunk, room < sizeof chunk ? room : sizeof chunk);
		if (n <= 0)
			break;
		for (ssize_t i = 0; i < n; i++)
			in_buf[(in_head + in_len + i) % IN_CAP] = chunk[i];
		in_len += n;
		bytes_from_host += n;
	}
	if (!connected) {
		bytes_dropped += out_len; /* nobody listens: a real board's bytes are lost too */
		out_len = 0;
		return;
	}
	size_t done = 0;
	while (done < out_len) {
		ssize_t n = write(pty_master, out_buf + done, out_len - done);
		if (n <= 0)
			break;
		done += n;
	}
	if (done) {
		memmove(out_buf, out_buf + done, out_len - done);
		out_len -= done;
		bytes_to_host += done;
	}
	if (!backpressure && out_len > BACKPRESSURE_HIGH) {
		bytes_dropped += out_len;
		out_len = 0;
	}
}

static int open_pty(char *name, size_t name_len) {
	int slave;
	if (openpty(&pty_master, &slave, NULL, NULL, NULL) < 0) {
		perror("openpty");
		return -1;
	}
	struct termios tio;
	tcgetattr(slave, &tio);
	cfmakeraw(&tio);
	tcsetattr(slave, TCSANOW, &tio);
	if (ttyname_r(slave, name, name_len) != 0) {
		perror("ttyname");
		return -1;
	}
	close(slave); /* the host opens it; POLLHUP on the master says whether one has */
	int flags = fcntl(pty_master, F_GETFL);
	fcntl(pty_master, F_SETFL, flags | O_NONBLOCK);
	return 0;
}

/* ---------------------------------------------------------------------- main -- */

static void sleep_hook(avr_t *avr, avr_cycle_count_t how_long) {
	(void)avr;
	(void)how_long; /* time is paced in the main loop, never slept away here */
}

static void usage(void) {
	fprintf(stderr, "usage: baro_board FIRMWARE.elf [--trajectory CSV] [--truth CSV] [--speed X]\n"
	                "                  [--address 0x76|0x77] [--sensor bmp280|ms5611] [--wait-host]\n"
	                "                  [--duration S] [--no-backpressure]\n");
}

int main(int argc, char **argv) {
	const char *trajectory_path = NULL, *truth_path = NULL;
	double speed = 1.0, duration = 0.0;
	int address = 0x76, wait_host = 0, use_ms5611 = 0;
	static const struct option options[] = {
		{"trajectory", required_argument, 0, 't'}, {"truth", required_argument, 0, 'r'},
		{"speed", required_argument, 0, 's'},      {"address", required_argument, 0, 'a'},
		{"wait-host", no_argument, 0, 'w'},        {"duration", required_argument, 0, 'd'},
		{"no-backpressure", no_argument, 0, 'n'},  {"help", no_argument, 0, 'h'},
		{"sensor", required_argument, 0, 'm'},
		{0, 0, 0, 0}};
	int opt;
	while ((opt = getopt_long(argc, argv, "", options, NULL)) != -1) {
		switch (opt) {
		case 't': trajectory_path = optarg; break;
		case 'r': truth_path = optarg; break;
		case 's': speed = atof(optarg); break;
		case 'a': address = (int)strtol(optarg, NULL, 0); break;
		case 'w': wait_host = 1; break;
		case 'd': duration = atof(optarg); break;
		case 'n': backpressure = 0; break;
		case 'm':
			if (strcmp(optarg, "ms5611") == 0) {
				use_ms5611 = 1;
			} else if (strcmp(optarg, "bmp280") != 0) {
				usage();
				return 2;
			}
			break;
		default: usage(); return 2;
		}
	}
	if (optind != argc - 1 || speed < 0 || (address != 0x76 && address != 0x77)) {
		usage();
		return 2;
	}
	if (trajectory_path && load_trajectory(trajectory_path) < 0)
		return 1;

	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_signal;
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (elf_read_firmware(argv[optind], &fw) != 0) {
		fprintf(stderr, "baro_board: cannot read %s\n", argv[optind]);
		return 1;
	}
	strcpy(fw.mmcu, "atmega328p");
	fw.frequency = F_CPU_HZ;
	avr_t *avr = avr_make_mcu_by_name(fw.mmcu);
	if (!avr)
		return 1;
	avr_init(avr);
	avr_load_firmware(avr, &fw);
	avr->frequency = F_CPU_HZ;
	avr->sleep = sleep_hook;
	avr->log = 0;

	out_buf = malloc(OUT_CAP);
	in_buf = malloc(IN_CAP);
	FILE *truth = NULL;
	if (truth_path) {
		truth = fopen(truth_path, "w");
		if (!truth) {
			perror(truth_path);
			return 1;
		}
		setvbuf(truth, NULL, _IOLBF, 0); /* whole lines only: a test may read it while we run */
		fprintf(truth, "read_us,meas_us,pressure_pa,temperature_c,adc_p,adc_t\n");
	}
	if (use_ms5611) {
		ms_attach(avr, &ms, (uint8_t)address);
		ms.dev.truth = truth;
	} else {
		bmp_attach(avr, &bmp, (uint8_t)address);
		bmp.dev.truth = truth;
	}

	uint32_t flags = 0; /* no stdio echo of UART bytes, no polling sleeps */
	avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
	uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
	                        uart_out_hook, NULL);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
	                        uart_xon_hook, NULL);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
	                        uart_xoff_hook, NULL);

	char pty_name[128];
	if (open_pty(pty_name, sizeof pty_name) < 0)
		return 1;
	printf("baro_board: pty %s\n", pty_name);
	fflush(stdout);
	dup2(STDERR_FILENO, STDOUT_FILENO); /* simavr's own messages must not clog a pipe */

	if (wait_host) {
		while (!stop_requested && !host_connected())
			usleep(2000);
		usleep(200000); /* let the host finish opening (pyserial flushes input on open) */
	}
	avr_cycle_timer_register_usec(avr, UART_BYTE_US, uart_feed_timer, NULL);

	double wall0 = wall_now();
	avr_cycle_count_t cycle0 = avr->cycle;
	avr_cycle_count_t service_every = avr_usec_to_cycles(avr, SERVICE_PERIOD_US);
	avr_cycle_count_t next_service = avr->cycle + service_every;
	avr_cycle_count_t end_cycle = duration > 0 ? cycle0 + (avr_cycle_count_t)(duration * F_CPU_HZ) : 0;
	int state = cpu_Running;
	while (!stop_requested) {
		state = avr_run(avr);
		if (state == cpu_Done || state == cpu_Crashed)
			break;
		if (avr->cycle < next_service)
			continue;
		next_service = avr->cycle + service_every;
		if (end_cycle && avr->cycle >= end_cycle)
			break;
		/* a watchdog reset of the AVR cancels every cycle timer, ours too */
		if (!avr_cycle_timer_status(avr, uart_feed_timer, NULL))
			avr_cycle_timer_register_usec(avr, UART_BYTE_US, uart_feed_timer, NULL);
		service_pty();
		while (backpressure && out_len > BACKPRESSURE_HIGH && !stop_requested) {
			usleep(1000);
			service_pty();
		}
		if (speed > 0) {
			double ahead = (avr->cycle - cycle0) / (double)F_CPU_HZ / speed - (wall_now() - wall0);
			if (ahead > 0.002)
				usleep((useconds_t)(ahead * 1e6));
		}
	}
	service_pty();
	double sim_s = (avr->cycle - cycle0) / (double)F_CPU_HZ, wall_s = wall_now() - wall0;
	fprintf(stderr,
	        "baro_board: %s after %.3f s simulated in %.3f s wall (x%.1f); "
	        "bytes to host %lu, from host %lu, dropped %lu; i2c transactions %lu (%lu unanswered), "
	        "data reads %lu\n",
	        state == cpu_Crashed ? "CRASHED" : "stopped", sim_s, wall_s,
	        wall_s > 0 ? sim_s / wall_s : 0.0, bytes_to_host, bytes_from_host, bytes_dropped,
	        bmp.dev.transactions + ms.dev.transactions, bmp.dev.nacked + ms.dev.nacked,
	        bmp.dev.data_reads + ms.dev.data_reads);
	if (truth)
		fclose(truth);
	close(pty_master);
	free(out_buf);
	free(in_buf);
	free(traj);
	avr_terminate(avr);
	return state == cpu_Crashed ? 3 : 0;
}
