"""What every figure shares: axes of a given size, a legend that covers nothing."""


def _axes(ax, figsize=(6.0, 4.5)):
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax.figure, ax


def _legend_below(ax, ncol=3, **kw):
    """The legend under the axes and their x label (a fixed distance, whatever the axes' height), where it covers
    nothing drawn."""
    from matplotlib.transforms import ScaledTranslation

    below = ax.transAxes + ScaledTranslation(0.0, -0.5, ax.figure.dpi_scale_trans)
    return ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=below, fontsize=8, ncol=ncol,
                     **kw)
