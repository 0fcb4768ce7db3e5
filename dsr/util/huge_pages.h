// Large buffers (frame data, pyramid levels) on transparent huge pages where the kernel
// gives them on request (THP "madvise" mode, Debian's default) and the environment asks
// for them (DSR_HUGE_PAGES=1): the first write of a fresh 2 MiB page is one page fault
// instead of 512. Off by default: on the 2-core development machine (a virtual machine)
// the kernel's time for huge pages grew until a clinical-size registration took 1.80x as
// long with them (22.4 against 12.5 s, system time 16.1 against 1.9 s; the paper's size
// 1.41x), where they had once saved 7 %. Poses are the same either way.
#ifndef DSR_UTIL_HUGE_PAGES_H_
#define DSR_UTIL_HUGE_PAGES_H_

#include <cstddef>
#include <cstdint>
#include <vector>

namespace dsr {

// Whether DSR_HUGE_PAGES=1 was set when first asked.
bool HugePagesRequested();

// Asks for huge pages on the 2 MiB-aligned interior of [data, data + bytes) when
// HugePagesRequested(). A hint: no effect where unsupported.
void AdviseHugePages(void* data, size_t bytes);

// v's storage emptied and reserved for n elements, advised for huge pages before it is
// first written (when it is large enough to hold one).
template <class T>
void ReserveWithHugePages(std::vector<T>* v, size_t n) {
  constexpr size_t kHugePage = size_t{2} << 20;
  std::vector<T>().swap(*v);  // fresh, untouched storage
  v->reserve(n);
  if (n * sizeof(T) >= 2 * kHugePage) AdviseHugePages(v->data(), n * sizeof(T));
}

// v = n copies of `value`, on storage advised as above.
template <class T>
void AssignWithHugePages(std::vector<T>* v, size_t n, const T& value) {
  ReserveWithHugePages(v, n);
  v->assign(n, value);
}

// v = [first, last), on storage advised as above (each element written once).
template <class T>
void AssignWithHugePages(std::vector<T>* v, const T* first, const T* last) {
  ReserveWithHugePages(v, static_cast<size_t>(last - first));
  v->assign(first, last);
}

}  // namespace dsr

#endif  // DSR_UTIL_HUGE_PAGES_H_
