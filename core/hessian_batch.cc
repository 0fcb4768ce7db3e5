#include "core/hessian_batch.h"

#include <glog/logging.h>

namespace dsr {

HessianBatcher::HessianBatcher(double* h, int n) : h_(h), n_(n) {}

void HessianBatcher::Add(int k,
                         const int* frame,
                         const double (*jac)[6],
                         const HessianWeights& weights) {
  DCHECK_GE(k, 1);
  uint32_t observers = 0;
  for (int a = 0; a < k; ++a) observers |= 1u << frame[a];
  ++clock_;
  Slot* slot = nullptr;
  for (Slot& s : slots_) {
    if (s.observers == observers) {
      slot = &s;
      break;
    }
  }
  if (slot == nullptr) {  // open a batch for this observer set: a free slot, else the LRU
    slot = &slots_[0];
    for (Slot& s : slots_) {
      if (s.observers == 0) {
        slot = &s;
        break;
      }
      if (s.last_use < slot->last_use) slot = &s;
    }
    if (slot->observers != 0) FlushSlot(slot);
    slot->observers = observers;
    slot->k = k;
    slot->weights = weights;
    for (int a = 0; a < k; ++a) slot->frame[a] = frame[a];
    if (slot->stacked.cols() != 6 * k) slot->stacked.resize(kRows, 6 * k);
  }
  slot->last_use = clock_;
  double* column = slot->stacked.data() + slot->rows;  // column-major: stride kRows
  for (int a = 0; a < k; ++a) {
    for (int i = 0; i < 6; ++i) column[(6 * a + i) * kRows] = jac[a][i];
  }
  if (++slot->rows == kRows) FlushSlot(slot);
}

void HessianBatcher::FlushSlot(Slot* slot) {
  if (slot->rows > 0) {
    const int k = slot->k, size = 6 * k;
    product_.setZero(size, size);
    product_.selfadjointView<Eigen::Upper>().rankUpdate(
        slot->stacked.topRows(slot->rows).transpose());
    for (int a = 0; a < k; ++a) {
      const int fa = slot->frame[a];
      for (int b = a; b < k; ++b) {
        const int fb = slot->frame[b];
        const double scale = slot->weights.shared + (a == b ? slot->weights.diagonal : 0.0);
        for (int i = 0; i < 6; ++i) {
          double* row = h_ + static_cast<int64_t>(6 * fa + i) * n_ + 6 * fb;
          // Diagonal blocks: on and above their diagonal only (P's lower part is unset).
          for (int j = a == b ? i : 0; j < 6; ++j) row[j] += scale * product_(6 * a + i, 6 * b + j);
        }
      }
    }
  }
  slot->rows = 0;
  slot->observers = 0;
}

void HessianBatcher::Flush() {
  for (Slot& s : slots_) FlushSlot(&s);
}

}  // namespace dsr
