/* J += C for two CSR blocks of the same rows, C's entries among J's (shoulder_fem.engine.subset_add).
 *
 * Both blocks have sorted columns in every row. jmap/cmap: the global ids of the blocks'
 * columns (an MPIAIJ matrix's off-diagonal block, whose local column numbers are its own), or
 * NULL where the local numbers are comparable (the diagonal block, a SeqAIJ matrix). One walk
 * along each row of J per row of C: no search, nothing allocated.
 *
 * add = 0: only count C's entries that J has not (nothing changed); add = 1: add them (the
 * caller has checked that none is missing). Returns the count of missing entries.
 */
#include <stdint.h>

#define SF_CSR_ADD(NAME, INT)                                                                 \
    long NAME(long m, const INT *ji, const INT *jj, double *ja, const INT *ci, const INT *cj, \
              const double *ca, const INT *jmap, const INT *cmap, int add)                    \
    {                                                                                         \
        long missing = 0;                                                                     \
        for (long r = 0; r < m; r++) {                                                        \
            INT p = ji[r], pe = ji[r + 1];                                                    \
            for (INT q = ci[r]; q < ci[r + 1]; q++) {                                         \
                INT c = cmap ? cmap[cj[q]] : cj[q];                                           \
                while (p < pe && (jmap ? jmap[jj[p]] : jj[p]) < c) p++;                       \
                if (p == pe || (jmap ? jmap[jj[p]] : jj[p]) != c) {                           \
                    missing++;                                                                \
                    continue;                                                                 \
                }                                                                             \
                if (add) ja[p] += ca[q];                                                      \
            }                                                                                 \
        }                                                                                     \
        return missing;                                                                       \
    }

SF_CSR_ADD(sf_csr_add32, int32_t)
SF_CSR_ADD(sf_csr_add64, int64_t)
